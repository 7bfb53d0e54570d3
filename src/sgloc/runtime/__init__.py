"""Running work: the one task runner (`tasks.run_all`: in process, local workers or Dask), worker
processes that end with their parent (`workers`) and per-stage timings (`timing.StageTimer`)."""
