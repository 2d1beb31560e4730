"""Simulated Franka Panda and tabletop objects (PyBullet) behind ROS 2 interfaces."""
