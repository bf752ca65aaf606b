"""The ``nephele`` command line and Dask render farm.

Commands read and write files through :mod:`nephele.fileio` and :mod:`nephele.volume_files`,
never through the add-on; only the Blender workers (:mod:`.worker`) load the add-on's frame
updaters (:mod:`nephele.addon.frame`), to bring a scene's layers to the frame they render.
"""
