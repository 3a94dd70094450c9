"""Curiosity-driven skill acquisition after Ngo, Luciw, Foerster and Schmidhuber (2013): the
algorithm, the worlds and the robot loop (core/), and curiosity_node and skill_node."""
