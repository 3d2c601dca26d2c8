"""What the command line and the daemon's plans both compute from files on disk: the calibration of a campaign
directory and the mass of a measurement directory. Pure of I/O beyond reading those files."""
