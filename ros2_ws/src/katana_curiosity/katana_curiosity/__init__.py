"""Curiosity-driven skill acquisition after Ngo, Luciw, Foerster and Schmidhuber (2013)."""
