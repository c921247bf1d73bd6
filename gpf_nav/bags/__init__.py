"""rosbag2 tools: ``gpf-nav record`` (the simulator's scenario written as a bag) and ``gpf-nav replay``
(the estimator run offline over a bag), with the bag reader/writer they share."""
