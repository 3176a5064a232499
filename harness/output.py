"""Run outputs: snapshots.h5 with an XDMF index for ParaView, series.csv, summary.json.

HDF5 layout: one group per output ``/snapshots/NNNNNN`` (attribute ``time``) holding
``position (n,2)``, ``velocity (n,2)``, ``pressure (n)``, ``stress (n,4)`` [sxx, syy,
sxy, szz], ``material (n)``, ``volume (n)``, ``jacobian (n)`` and ``corners (n,4,2)``
(CPDI domain corners, counter-clockwise). Runs with incompressible water add the cell
fields ``grid/pressure``, ``grid/fill`` and ``grid/water`` (ny, nx), x fastest, with
attributes ``origin`` and ``h``. ``snapshots.xdmf`` is a temporal collection of polyvertex
grids pointing at the particle datasets, plus (when there are cell fields) a temporal
collection of 2D co-rectilinear meshes carrying them as cell data; it is rewritten after
every snapshot, so it is valid whenever the run stops.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from typing import Any

import h5py
import numpy as np

FIELDS_XDMF = {  # name -> (AttributeType, components)
    "velocity": ("Vector", 2),
    "pressure": ("Scalar", 1),
    "stress": ("Tensor6", 4),
    "material": ("Scalar", 1),
    "volume": ("Scalar", 1),
    "jacobian": ("Scalar", 1),
}


def corners(x: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Domain corners (n,4,2) from centres x (n,2) and half-vectors r (n,4)."""
    r1, r2 = r[:, 0:2], r[:, 2:4]
    return np.stack([x - r1 - r2, x + r1 - r2, x + r1 + r2, x - r1 + r2], axis=1)


class SnapshotWriter:
    """Appends particle snapshots to HDF5 and keeps the XDMF index current."""

    def __init__(self, run_dir: Path, keep: int | None = None):
        """A new file; or, with ``keep`` (a restart), the existing file cut back to its first
        ``keep`` snapshots (ValueError if it holds fewer)."""
        self.h5_path = run_dir / "snapshots.h5"
        self.xdmf_path = run_dir / "snapshots.xdmf"
        self._f = h5py.File(self.h5_path, "w" if keep is None else "r+")
        self._times: list[tuple[str, float, int]] = []
        if keep is None:
            self._grp = self._f.create_group("snapshots")
            return
        try:
            self._grp = self._f["snapshots"]
            names = sorted(self._grp)
            if len(names) < keep:
                raise ValueError(f"it holds {len(names)}")
            for name in names[keep:]:
                del self._grp[name]
            self._times = [(n, float(self._grp[n].attrs["time"]), self._grp[n]["position"].shape[0])
                           for n in names[:keep]]
            if keep:
                self._write_xdmf([k for k in FIELDS_XDMF if k in self._grp[names[keep - 1]]])
        except BaseException:
            self.close()
            raise

    def write(self, t: float, fields: dict[str, np.ndarray], grid: dict | None = None) -> None:
        """One snapshot: particle fields, and optionally cell fields ``grid`` = {origin, h,
        name: array (nx, ny), ...} (stored transposed, x fastest)."""
        name = f"{len(self._times):06d}"
        g = self._grp.create_group(name)
        g.attrs["time"] = t
        for key, arr in fields.items():
            g.create_dataset(key, data=np.ascontiguousarray(arr), compression="gzip", compression_opts=1)
        if grid is not None:
            gg = g.create_group("grid")
            gg.attrs["origin"] = np.asarray(grid["origin"], dtype=float)
            gg.attrs["h"] = float(grid["h"])
            for key, arr in grid.items():
                if key not in ("origin", "h"):
                    gg.create_dataset(key, data=np.ascontiguousarray(np.asarray(arr).T), compression="gzip",
                                      compression_opts=1)
        self._f.flush()
        self._times.append((name, t, fields["position"].shape[0]))
        self._write_xdmf(list(fields))

    def _write_xdmf(self, keys: list[str]) -> None:
        h5 = self.h5_path.name
        out = ['<?xml version="1.0" ?>', '<Xdmf Version="3.0">', "<Domain>",
               '<Grid Name="particles" GridType="Collection" CollectionType="Temporal">']
        for name, t, n in self._times:
            base = f"{h5}:/snapshots/{name}"
            out.append(f'<Grid Name="t{name}" GridType="Uniform"><Time Value="{t:.9g}"/>')
            out.append(f'<Topology TopologyType="Polyvertex" NumberOfElements="{n}"/>')
            out.append(f'<Geometry GeometryType="XY"><DataItem Dimensions="{n} 2" NumberType="Float" '
                       f'Precision="8" Format="HDF">{base}/position</DataItem></Geometry>')
            for key in keys:
                if key not in FIELDS_XDMF:
                    continue
                atype, comp = FIELDS_XDMF[key]
                dims = f"{n}" if comp == 1 else f"{n} {comp}"
                ntype = "Int" if key == "material" else "Float"
                prec = "4" if key == "material" else "8"
                atype = "Matrix" if comp == 4 else atype
                out.append(f'<Attribute Name="{key}" AttributeType="{atype}" Center="Node">'
                           f'<DataItem Dimensions="{dims}" NumberType="{ntype}" Precision="{prec}" '
                           f'Format="HDF">{base}/{key}</DataItem></Attribute>')
            out.append("</Grid>")
        out.append("</Grid>")
        out += self._grid_xdmf(h5)
        out += ["</Domain>", "</Xdmf>"]
        write_text_atomic(self.xdmf_path, "\n".join(out) + "\n")

    def _grid_xdmf(self, h5: str) -> list[str]:
        """The cell fields' temporal collection (2DCoRectMesh; XDMF orders y before x)."""
        named = [(n, t) for n, t, _ in self._times if "grid" in self._grp[n]]
        if not named:
            return []
        out = ['<Grid Name="cells" GridType="Collection" CollectionType="Temporal">']
        for name, t in named:
            gg = self._grp[name]["grid"]
            keys = [k for k in gg if isinstance(gg[k], h5py.Dataset)]
            ny, nx = gg[keys[0]].shape
            ox, oy = gg.attrs["origin"]
            h = gg.attrs["h"]
            out.append(f'<Grid Name="c{name}" GridType="Uniform"><Time Value="{t:.9g}"/>')
            out.append(f'<Topology TopologyType="2DCoRectMesh" Dimensions="{ny + 1} {nx + 1}"/>')
            out.append('<Geometry GeometryType="ORIGIN_DXDY">'
                       f'<DataItem Dimensions="2" NumberType="Float" Format="XML">{oy:.9g} {ox:.9g}</DataItem>'
                       f'<DataItem Dimensions="2" NumberType="Float" Format="XML">{h:.9g} {h:.9g}</DataItem>'
                       '</Geometry>')
            for key in keys:
                ntype, prec = ("Int", "4") if gg[key].dtype.kind == "i" else ("Float", "8")
                out.append(f'<Attribute Name="{key}" AttributeType="Scalar" Center="Cell">'
                           f'<DataItem Dimensions="{ny} {nx}" NumberType="{ntype}" Precision="{prec}" '
                           f'Format="HDF">{h5}:/snapshots/{name}/grid/{key}</DataItem></Attribute>')
            out.append("</Grid>")
        out.append("</Grid>")
        return out

    def close(self) -> None:
        if self._f:
            self._f.close()
            self._f = None


class SeriesWriter:
    """series.csv, one row per sample, flushed as it goes."""

    def __init__(self, path: Path, columns: list[str]):
        self.columns = columns
        self._fh = path.open("w", newline="")
        self._w = csv.writer(self._fh)
        self._w.writerow(columns)

    def write(self, row: dict[str, float]) -> None:
        self._w.writerow([f"{row[c]:.10g}" for c in self.columns])
        self._fh.flush()

    def close(self) -> None:
        self._fh.close()


def write_text_atomic(path: Path, text: str) -> None:
    """Write a text file atomically (temporary file beside it, then rename)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write JSON atomically."""
    write_text_atomic(path, json.dumps(data, indent=2, default=_jsonable) + "\n")


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def read_series(path: Path) -> dict[str, np.ndarray]:
    """series.csv as a dict of columns."""
    data = np.genfromtxt(path, delimiter=",", names=True)
    return {name: np.atleast_1d(data[name]) for name in data.dtype.names}
