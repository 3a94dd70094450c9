"""Katana kinematics, pick-and-place planning (core/) and pick_place_executor."""
