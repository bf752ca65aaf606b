"""A steady velocity on an unstructured grid (VTK XML ``.vtu``), interpolated in its cells.

The point vectors are interpolated with each cell's own interpolation
functions (VTK's ``vtkProbeFilter`` over a static cell locator); points
outside every cell get NaN, which :func:`~nephele.core.flowvol.flow_volume`
reports as a :class:`DataError` naming the field.

References
----------
.. [1] N. Max, B. Becker and R. Crawfis, "Flow volumes for interactive vector
   field visualization", Proc. Visualization '93, 19-24.
"""

from pathlib import Path

import numpy as np

from ..errors import DataError


class UnstructuredVelocity:
    """``velocity(points (n, 3), t) -> (n, 3)`` from the point vectors ``field`` of a ``.vtu`` file."""

    def __init__(self, path, field="uvw"):
        import vtk
        from vtk.util.numpy_support import vtk_to_numpy

        self.path, self.field = str(path), field
        if not Path(path).is_file():
            raise DataError("no such file", path=self.path)
        reader = vtk.vtkXMLUnstructuredGridReader()
        reader.SetFileName(self.path)
        reader.Update()
        grid = reader.GetOutput()
        if grid is None or grid.GetNumberOfCells() == 0:
            raise DataError("is not a VTK XML unstructured grid with cells", path=self.path)
        arr = grid.GetPointData().GetArray(field)
        if arr is None or arr.GetNumberOfComponents() != 3:
            raise DataError("is not a 3-component point array of the grid", path=self.path, field=field)
        grid.GetPointData().SetActiveVectors(field)
        self.grid = grid
        self.bounds = np.array(grid.GetBounds()).reshape(3, 2)
        self.points = vtk_to_numpy(grid.GetPoints().GetData()).astype(np.float64)
        self.vectors = vtk_to_numpy(arr).astype(np.float64)
        self._locator = vtk.vtkStaticCellLocator()
        self._locator.SetDataSet(grid)
        self._locator.BuildLocator()
        self._vtk, self._to_numpy = vtk, vtk_to_numpy

    def __call__(self, points, t=None):
        from vtk.util.numpy_support import numpy_to_vtk

        vtk = self._vtk
        p = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
        pts = vtk.vtkPoints()
        pts.SetData(numpy_to_vtk(p, deep=1))
        probe_in = vtk.vtkPolyData()
        probe_in.SetPoints(pts)
        probe = vtk.vtkProbeFilter()
        probe.SetInputData(probe_in)
        probe.SetSourceData(self.grid)
        # Reuse the prebuilt locator (VTK >= 9.4 has SetCellLocator; older only the prototype).
        (probe.SetCellLocator if hasattr(probe, "SetCellLocator") else probe.SetCellLocatorPrototype)(self._locator)
        probe.Update()
        out = probe.GetOutput()
        v = self._to_numpy(out.GetPointData().GetArray(self.field)).astype(np.float64).reshape(-1, 3)
        valid = self._to_numpy(out.GetPointData().GetArray(probe.GetValidPointMaskArrayName())).astype(bool)
        v[~valid] = np.nan
        return v
