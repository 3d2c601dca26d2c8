"""What the command line and the daemon's plans both compute from files on disk, one code path for both: the
calibration of a campaign directory (:mod:`.calibration`), the mass of a measurement directory (:mod:`.mass`), the
CoG (:mod:`.cog`) and the inertia (:mod:`.inertia`) of a properties run directory, and the reference weighing of a
run (:mod:`.reference`). Pure of I/O beyond reading those files."""
