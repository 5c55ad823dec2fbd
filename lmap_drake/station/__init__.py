"""Stations: the simulated plant world or the real UR5 cell, with one port
contract (see ``lmap_drake.station.station.MakeStation``).

``MakeStation`` and ``STATION_PORTS`` are loaded lazily so that light
modules (e.g. ``hardware_config``, imported by the scenario) do not pull in
the station and its dependencies."""


def __getattr__(name):
    if name in ("MakeStation", "STATION_PORTS"):
        from lmap_drake.station import station
        return getattr(station, name)
    raise AttributeError(name)
