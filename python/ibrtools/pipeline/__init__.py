"""The pipeline: the stage planner and runners (``stages``), render jobs (``job``), parameter
sweeps (``sweep``), batches of targets (``batches``), the HTML report (``report_html``) and the
Dask workers (``distributed``). It calls the families and the method registry; only the API
and the command line call it.
"""
