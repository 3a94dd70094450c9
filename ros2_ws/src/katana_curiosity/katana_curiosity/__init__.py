"""Curiosity-driven skill acquisition after Ngo, Luciw, Foerster and Schmidhuber (2013)."""

import importlib.util as _importlib_util

# gymnasium.make("katana_curiosity/BlocksWorld-v0") works after `import katana_curiosity`.
if _importlib_util.find_spec("gymnasium") is not None:
    from .core.gym_env import register as _register_gymnasium_env

    _register_gymnasium_env()
