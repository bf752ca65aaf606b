"""The ``nephele`` command line and Dask render farm (never needs the add-on)."""
