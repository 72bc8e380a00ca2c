"""The steep wall of a drawn cup that sim.stepping.split_ring cuts its ring from: the solver's
criterion, in a module of its own so that sim.frames.rings (and through it the server, which
never imports the solver) reads the same number without importing the split-ring stage."""

# an element belongs to the wall when its formed mid-surface is steeper than this (degrees from
# the horizontal): the bottom and the flange are flat, the punch and die radii turn between
WALL = 60.0
