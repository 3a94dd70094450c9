"""The research harness: the paper's experiments, sweeps, metrics, figures, the robot truth,
the robot reproduction and its report, and the command lines `katana-curiosity` and
`katana-robot`. It sits above the node packages and katana_bringup and imports from them; none
of them imports from it."""

from .gym_env import register as _register_gymnasium_env

# gymnasium.make("katana_paper/BlocksWorld-v0") works after `import katana_paper`.
_register_gymnasium_env()
