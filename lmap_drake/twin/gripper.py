"""The digital twin's 2F-85: the Robotiq registers over the simulated
fingers (``twin.Twin`` sets what they measure; ``robotiq_server`` serves
the registers on the Robotiq socket)."""
from __future__ import annotations

import threading

import numpy as np

from lmap_drake.station.hardware.robotiq_client import OpeningToPos, PosToOpening


class TwinGripper:
    """2F-85 registers (ACT, GTO, POS, PRE, OBJ, STA, ...) over the simulated
    gripper: ``SET POS`` requests an opening, ``GET POS`` reads the
    simulated fingers, OBJ is 2 when they stand still short of a closing
    request or the plant world holds the leaf between them (an object
    between the pads), 3 at the request. While it holds, ``GET POS`` never
    reads wider than ``held_at`` (POS where the pads met the leaf): a
    2F-85 stopped on an object stands there, while the simulated fingers
    may bounce off the held leaf region (the held station's coarser step)
    and a wider reading would make the controller's hold request open them."""

    def __init__(self, config, opening: float):
        self.config = config
        self.lock = threading.Lock()
        self.regs = {k: 0 for k in ("ACT", "GTO", "ATR", "ADR", "POS", "PRE", "SPE", "FOR",
                                    "OBJ", "STA", "FLT", "MOD")}
        pos = OpeningToPos(opening, config)
        self.regs.update(POS=pos, PRE=pos, OBJ=3)
        self._still_since = None
        self.holding = False        # the plant world holds the leaf between the pads
        self.held_at = None         # POS where the pads met the held leaf

    def Set(self, values: dict) -> bool:
        with self.lock:
            if any(k not in self.regs for k in values) or any(
                    not 0 <= int(v) <= 255 for v in values.values()):
                return False       # one-byte registers: out of range is not acknowledged
            values = dict(values)
            requested = values.pop("POS", None)
            self.regs.update(values)
            if values.get("ACT") == 1:
                self.regs["STA"] = 3          # activation is instant here
            elif values.get("ACT") == 0:
                self.regs["STA"] = 0
            if requested is not None:
                self.regs["PRE"] = int(requested)
                self.regs["OBJ"] = 0
        return True

    def Get(self, var: str):
        with self.lock:
            return self.regs.get(var)

    def RequestedOpening(self) -> float:
        with self.lock:
            if self.regs["STA"] != 3 or self.regs["GTO"] != 1:
                return None
            return PosToOpening(self.regs["PRE"], self.config)

    def SetMeasured(self, opening: float, rate: float, t: float) -> None:
        """The simulated fingers at simulated time ``t``: an object is
        reported once they stood still short of the request for 0.1 s (not
        in the instant a new request arrives, before they move)."""
        with self.lock:
            pos = OpeningToPos(float(np.clip(opening, 0.0, 0.085)), self.config)
            if self.holding and self.held_at is not None:
                pos = max(pos, self.held_at)      # not wider than where they met the leaf
            self.regs["POS"] = pos
            still_short = abs(pos - self.regs["PRE"]) > 1 and abs(rate) < 1e-3
            if not still_short:
                self._still_since = None
            elif self._still_since is None:
                self._still_since = t
            if self.holding:        # the leaf between the pads stops them
                self.regs["OBJ"] = 2
            elif abs(pos - self.regs["PRE"]) <= 1:
                self.regs["OBJ"] = 3
            elif still_short and t - self._still_since >= 0.1 - 1e-9:
                self.regs["OBJ"] = 2 if pos < self.regs["PRE"] else 1   # 2: stalled closing
            else:
                self.regs["OBJ"] = 0
