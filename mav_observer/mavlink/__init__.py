"""MAVLink input for mav-observer: the dialect (chosen in one place), tlog and connection
readers, message adapters with their frame chains, the time base and the tracker that feeds
one observer per vehicle and target. See ``docs/frames.md``."""
