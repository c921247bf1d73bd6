"""The simulation: the lunar-descent scenario (truth and measurements), the descent's sensor suite, and the
playback schedule the simulator node and replay publish from. Seeded; no ROS."""
