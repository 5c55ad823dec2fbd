"""The hardware station: thin clients for the UR5 (ur_rtde), the Robotiq
2F-85 (URCap socket or Modbus RTU) and the RealSense L515 (pyrealsense2), the safety
checks in front of the arm, and the LeafSystems that give them the station
port contract. The client libraries are imported lazily, only when real
hardware is connected (``pip install -e .[hardware]``)."""
