"""Stations: the simulated plant world or the real UR5 cell, with one port
contract (see ``MakeStation``)."""
from lmap_drake.station.station import MakeStation, STATION_PORTS  # noqa: F401
