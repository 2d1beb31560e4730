"""Task-space region RRT planner (Scholz and Stilman 2010) as a ROS 2 node."""
