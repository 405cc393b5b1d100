"""The simulated world: geometry (:mod:`.world`), the laser's view of it (:mod:`.raycast`) and the
robot body in it (:mod:`.physics`). Units: metres, radians; poses ``(x, y, theta)`` in the world
frame unless a docstring says otherwise."""
