"""A fleet of logged drives on Dask: find the drives (``drives``), process one
(``drive_run``), run them all on a cluster and write the summary (``cluster``)."""
