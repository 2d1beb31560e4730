"""Object pose estimation from simulated camera images."""
