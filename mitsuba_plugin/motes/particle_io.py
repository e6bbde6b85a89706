"""Particle sets on disk: positions (scene units), radii (micrometres) and species indices.

================  ==========================================================================================
``.npz``          arrays ``positions`` (n, 3), ``radii_um`` (n,), optional ``species`` (n,) ints
``.npy``          one (n, 4) or (n, 5) array: x, y, z, radius_um[, species]
``.csv``          a header line naming the columns ``x,y,z,radius_um`` (``species`` optional, any order),
                  then one particle per line
``.ply``          a point cloud, ASCII or binary (read and written with ``meshio``): vertex ``x y z`` plus
                  ``radius`` (micrometres) or Houdini's ``pscale`` (scene units, converted with ``scale_m``),
                  optional ``species``
================  ==========================================================================================

``load_particles(path, scale_m=1.0, n_species=None)`` validates everything and raises ``ValueError`` naming the
file and the element (particle index or file line) and field: non-finite coordinates, non-positive radii,
unknown species, empty sets, malformed files. Nothing else escapes from a bad file.
"""

from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass

import numpy as np


@dataclass
class ParticleSet:
    positions: np.ndarray  # (n, 3) scene units
    radii_um: np.ndarray  # (n,)
    species: np.ndarray  # (n,) integers (their type as read; int64 for non-integer input)

    def __len__(self) -> int:
        return int(self.positions.shape[0])


class ParticleFileError(ValueError):
    """A particle file that cannot be used; the message names the file and the element or field."""


#: Particles checked per step (bounds the validation's temporaries to a few MB).
_CHUNK = 1 << 20


def _fail(path, message: str):
    raise ParticleFileError(f"{path}: {message}")


def _validate(path, pos, radii, species, n_species) -> ParticleSet:
    pos = np.asarray(pos, dtype=np.float64)
    radii = np.asarray(radii, dtype=np.float64).ravel()
    if pos.ndim != 2 or pos.shape[1] != 3:
        _fail(path, f"positions must have shape (n, 3), got {pos.shape}")
    n = pos.shape[0]
    if n == 0:
        _fail(path, "the particle set is empty")
    if radii.size != n:
        _fail(path, f"{radii.size} radii for {n} particles")
    # Checked in chunks, so that 1e8 particles cost no full-size temporaries (masks, float copies).
    species = np.zeros(n, dtype=np.uint32) if species is None else np.asarray(species).ravel()
    if species.size != n:
        _fail(path, f"{species.size} species entries for {n} particles")
    limit = n_species if n_species is not None else np.inf
    for a in range(0, n, _CHUNK):
        sl = slice(a, min(a + _CHUNK, n))
        bad = ~np.isfinite(pos[sl])
        if bad.any():
            i, k = map(int, np.argwhere(bad)[0])
            _fail(path, f"particle {a + i}: field {'xyz'[k]} is {pos[a + i, k]} (must be finite)")
        bad = ~(np.isfinite(radii[sl]) & (radii[sl] > 0))
        if bad.any():
            i = a + int(np.flatnonzero(bad)[0])
            _fail(path, f"particle {i}: field radius is {radii[i]} (must be finite and > 0 micrometres)")
        sp = np.asarray(species[sl], dtype=np.float64)
        bad = ~(np.isfinite(sp) & (sp == np.round(sp)) & (sp >= 0) & (sp < limit))
        if bad.any():
            i = a + int(np.flatnonzero(bad)[0])
            suffix = f" (have {n_species} species)" if n_species is not None else ""
            _fail(path, f"particle {i}: field species is {species[i]}, not a known species index{suffix}")
    # Integer species keep their type (an int64 copy of 1e8 is 800 MB); others become integers.
    if species.dtype.kind not in "iu":
        species = species.astype(np.int64)
    return ParticleSet(np.ascontiguousarray(pos), np.ascontiguousarray(radii), species)


def _read_csv(path):
    with open(path, encoding="utf-8") as f:
        header = f.readline()
    names = [h.strip().lower() for h in header.strip().split(",")]
    for req in ("x", "y", "z", "radius_um"):
        if req not in names:
            _fail(path, f"line 1: the header must name column {req!r} (got {header.strip()!r})")
    with open(path, encoding="utf-8") as f:
        if not any(line.strip() for line in list(f)[1:]):
            _fail(path, "the particle set is empty")
    try:
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2, dtype=np.float64)
    except ValueError as exc:  # numpy names the line ("... at row k, column j")
        _fail(path, f"malformed CSV: {exc} (rows counted after the header line)")
    if data.size == 0:
        _fail(path, "the particle set is empty")
    if data.shape[1] != len(names):
        _fail(path, f"{data.shape[1]} columns per line but the header names {len(names)}")
    col = {n: data[:, i] for i, n in enumerate(names)}
    return np.column_stack([col["x"], col["y"], col["z"]]), col["radius_um"], col.get("species")


def _read_ply(path, scale_m):
    import meshio  # noqa: PLC0415

    # meshio.read() ends the process (sys.exit) when no reader accepts a file; the PLY reader itself
    # raises ordinary exceptions, and SystemExit is caught too so that a bad file can never kill a render.
    # meshio's header reader loops forever at end of file: a header cut before end_header must fail here.
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    if b"end_header" not in head:
        _fail(path, "malformed PLY: no end_header line in the header (truncated or not a PLY file)")
    try:
        mesh = meshio.ply.read(path)
    except (Exception, SystemExit) as exc:  # noqa: BLE001
        _fail(path, f"malformed PLY: {type(exc).__name__}: {exc}")
    data = {k.lower(): np.asarray(v) for k, v in mesh.point_data.items()}
    if "radius" in data:
        radii = data["radius"].astype(np.float64)
    elif "pscale" in data:
        radii = data["pscale"].astype(np.float64) * scale_m * 1e6  # scene units -> micrometres
    else:
        _fail(path, "vertex element has neither a 'radius' (micrometres) nor a 'pscale' (scene units) property")
    return mesh.points[:, :3] if mesh.points.shape[1] >= 3 else mesh.points, radii, data.get("species")


def load_particles(path, *, scale_m: float = 1.0, n_species: int | None = None) -> ParticleSet:
    """Read and validate a particle set (module docs)."""
    path = os.fspath(path)
    if not (np.isfinite(scale_m) and scale_m > 0):
        raise ValueError(f"invalid scale_m = {scale_m}: must be finite and > 0")
    suffix = pathlib.Path(path).suffix.lower()
    if not os.path.exists(path):
        _fail(path, "no such file")
    try:
        if suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                for key in ("positions", "radii_um"):
                    if key not in z:
                        _fail(path, f"missing array {key!r} (has {sorted(z.files)})")
                pos, radii, species = z["positions"], z["radii_um"], z["species"] if "species" in z else None
        elif suffix == ".npy":
            arr = np.load(path, allow_pickle=False)
            if arr.ndim != 2 or arr.shape[1] not in (4, 5):
                _fail(path, f"expected an (n, 4) or (n, 5) array x, y, z, radius_um[, species], got shape {arr.shape}")
            pos, radii, species = arr[:, :3], arr[:, 3], arr[:, 4] if arr.shape[1] == 5 else None
        elif suffix == ".csv":
            pos, radii, species = _read_csv(path)
        elif suffix == ".ply":
            pos, radii, species = _read_ply(path, scale_m)
        else:
            _fail(path, f"unknown particle file type {suffix!r} (use .npz, .npy, .csv or .ply)")
    except ParticleFileError:
        raise
    except Exception as exc:  # noqa: BLE001 - a malformed file may make any parser raise anything
        _fail(path, f"unreadable {suffix} file: {type(exc).__name__}: {exc}")
    return _validate(path, pos, radii, species, n_species)


def save_particles(path, pset: ParticleSet, *, scale_m: float = 1.0, binary: bool = True) -> None:
    """Write a particle set in the format given by the file suffix (PLY gets ``radius`` in micrometres)."""
    path = os.fspath(path)
    p = _validate(path, pset.positions, pset.radii_um, pset.species, None)
    suffix = pathlib.Path(path).suffix.lower()
    if suffix == ".npz":
        np.savez(path, positions=p.positions, radii_um=p.radii_um, species=p.species)
    elif suffix == ".npy":
        np.save(path, np.column_stack([p.positions, p.radii_um, p.species]))
    elif suffix == ".csv":
        np.savetxt(path, np.column_stack([p.positions, p.radii_um, p.species]), delimiter=",",
                   header="x,y,z,radius_um,species", comments="", fmt=["%.17g"] * 4 + ["%d"])
    elif suffix == ".ply":
        import meshio  # noqa: PLC0415

        meshio.write(path, meshio.Mesh(p.positions, [], point_data={"radius": p.radii_um, "species": p.species.astype(np.int32)}),
                     file_format="ply", binary=binary)
    else:
        _fail(path, f"unknown particle file type {suffix!r} (use .npz, .npy, .csv or .ply)")


__all__ = ["ParticleFileError", "ParticleSet", "load_particles", "save_particles"]
