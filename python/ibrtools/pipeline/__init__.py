"""The pipeline: the import stage (``importing``) and the derived stages' planner and runners
(``stages``, with the mix stage's fit in ``mix``), render jobs (``plan``: the cameras; ``job``: the
rendering, the outputs and the report), parameter sweeps (``sweep``), batches of targets
(``batches``), the HTML report (``report_html``) and the Dask workers (``distributed``). It calls
the families and the method registry; only the API and the command line call it.
"""
