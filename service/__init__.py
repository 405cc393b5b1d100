"""The asrmap process: configuration, wiring of drivers to the mapper, Zenoh, the map store,
the command line, simulated worlds and log replay.

Data flows one way: ``pioneer``/``laser`` (bytes -> typed readings) -> ``service`` (time
alignment, wiring) -> ``mapper`` (readings -> map + events) -> ``service`` (Zenoh, store, CLI).
"""
