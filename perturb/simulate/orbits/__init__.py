"""Periodic orbits on a flow: shooting, collocation and the search for every orbit at one
forcing frequency."""
