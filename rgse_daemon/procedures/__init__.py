"""Plans (warm-up, measurement run, mass-properties run, calibration campaign, reference weighing) and the engine
that runs them.

* :mod:`.messages` — what a plan yields (dry runs execute only the ``inert`` types); :mod:`.documents` — the run
  documents a plan yields to be recorded (``OpenRun`` … ``CloseRun``); :mod:`.engine` — :class:`RunEngine` (the
  run skeleton, finaliser, pause/resume/abort, dry run, interlock monitor, :class:`EngineState`); :mod:`.events` —
  progress events for MQTT and the CLI; :mod:`.recorder` — the store recorder, the one writer of the store here.
* :mod:`.measurement` — the in-line measurement run (Fig. 24); :mod:`.properties` — the mass-properties run (mass,
  then the CoG poses) with :mod:`.inertia`, its inertia step; :mod:`.calibration` — the campaign (Fig. 23, Table 1)
  with its torsional points; :mod:`.reference` — the crane-scale reference weighing of Table 2.
* What they share, one job each: :mod:`.settings` (``RunSettings``), :mod:`.preconditions` (verify the controller),
  :mod:`.programs` (render, check, run a KRL program, the PTP to a pose; the trace configuration), :mod:`.warmup`
  (warm-up and the preparation of a run), :mod:`.loop` (one measurement loop), :mod:`.directory` (manifest, durable
  writes);
  :mod:`.retrieval` — trace files from the controller into the archive.
"""
