"""The digital twin (``lmap-drake twin``): the simulated plant world behind
the hardware protocols, so that ``lmap-drake run --hardware`` runs a whole
episode without a robot.

- ``twin``: ``Twin`` (the plant world, paced, with the grasp made as in
  simulation, scored), ``TwinOptions``;
- ``gripper``: ``TwinGripper``, the 2F-85's registers over the simulated
  fingers;
- ``ur_emulator``: an EMULATOR of a Universal Robots controller for the real
  ``ur_rtde`` client (``python -m lmap_drake.twin.ur_emulator``);
- ``robotiq_server``: the Robotiq URCap socket over a register model;
- ``camera_server``: camera frames rendered from the plant world.

The station never imports the twin: it speaks the same protocols to it as
to the real devices.
"""
