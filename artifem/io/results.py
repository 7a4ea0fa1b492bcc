"""Time-series output of FEM fields for ParaView.

Uses dolfinx.io.VTXWriter (ADIOS2 .bp directory) when DOLFINx was built with
ADIOS2 (the dolfinx-solver-real wheel is), else dolfinx.io.XDMFFile (.xdmf/.h5,
which holds only fields of the mesh's own degree).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import dolfinx.common
import dolfinx.io
from dolfinx import fem

from artifem.errors import InputError


class ResultWriter:
    """Write one or more Functions of one mesh at successive times.

    ``ResultWriter(path, [u, stress])`` then ``write(t)`` after each step;
    usable as a context manager.  The suffix of ``path`` is replaced by .bp
    (VTX) or .xdmf (fallback); parent directories are created.  With VTX all
    functions must share one element type (dolfinx checks and raises).
    """

    def __init__(
        self,
        path: str | Path,
        functions: fem.Function | Sequence[fem.Function],
        engine: str = "BP4",
    ):
        self.functions = [functions] if isinstance(functions, fem.Function) else list(functions)
        if not self.functions:
            raise InputError("ResultWriter needs at least one Function to write")
        msh = self.functions[0].function_space.mesh
        self.comm = msh.comm
        self.use_vtx = dolfinx.common.has_adios2
        self.path = Path(path).with_suffix(".bp" if self.use_vtx else ".xdmf")
        if self.comm.rank == 0:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        self.comm.barrier()
        if self.use_vtx:
            self._writer = dolfinx.io.VTXWriter(self.comm, self.path, self.functions, engine=engine)
        else:
            self._writer = dolfinx.io.XDMFFile(self.comm, self.path, "w")
            self._writer.write_mesh(msh)

    def write(self, t: float) -> None:
        """Write the current values of all functions at time ``t``."""
        if self.use_vtx:
            self._writer.write(float(t))
        else:
            for f in self.functions:
                self._writer.write_function(f, float(t))

    def close(self) -> None:
        """Flush and close the file."""
        self._writer.close()

    def __enter__(self) -> ResultWriter:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
