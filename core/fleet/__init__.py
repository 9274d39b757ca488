"""mtcomp.fleet: the nightly diagnosis of many machines on Dask distributed, kept as a Parquet
dataset partitioned by machine and date, and the parameters' trends with warnings.

Modules: source (the machine-nights of a folder or manifest), adapter (the one call into
mtcomp.diagnose), night (one machine-night on a worker: its rows), dataset (Parquet, atomic
per partition), run (the Dask client), trend (series, change and limit tests), report (HTML),
generate (a fleet with known parameter histories), cli.  Dask and pyarrow are the optional
extra ``mtcomp[fleet]``, imported only when a fleet is run or read.
"""
