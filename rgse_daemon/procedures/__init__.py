"""Plans (warm-up, measurement run, calibration campaign) and the engine that runs them.

* :mod:`.messages` — what a plan yields; :mod:`.engine` — :class:`RunEngine` (finaliser, pause/resume/abort, dry
  run, interlock monitor, progress events); :mod:`.events` — the event/progress interface for MQTT and the CLI.
* :mod:`.measurement` — the in-line measurement run (Fig. 24); :mod:`.calibration` — the campaign (Fig. 23, Table 1);
  :mod:`.retrieval` — trace files from the controller into the archive; :mod:`.common` — what they share.
"""
