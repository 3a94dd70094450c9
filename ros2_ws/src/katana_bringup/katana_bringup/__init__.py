"""Bring-up of the Katana node graph: katana-run, launch files, parameters."""
