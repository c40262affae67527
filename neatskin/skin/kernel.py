"""The pinch kernel: a channel's area ratio A/A0 against the horizontal distance from the round probe's axis and
its depth, from the finite-element press (skin/mechanics.py) carried onto the round probe (skin/quasi3d.py);
computing it, its parquet file with provenance, the packaged and cached copies keyed by content, and its
vectorised bilinear interpolation."""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from neatskin.skin.fesetup import SHUT_AREA_RATIO, Material, PressGeometry, SolverSettings
from neatskin.skin.quasi3d import fill_unsolved
from neatskin.skin.scratch import arrays

KERNEL_FORMAT = 2  # bump when the solver's output for the same settings changes (2: quasi-3D transfer)
PAPER_KERNEL = "paper_pinch_kernel.parquet"  # in neatskin/protocols/skins/
DEFAULT_OFFSETS_MM = tuple(np.round(np.arange(0.0, 10.0001, 0.5), 6))
SPREAD_MM = 1.0  # the quasi-3D transfer's uncertainty reads the strip's table this far to either side (half a width)


@dataclass(frozen=True)
class KernelSpec:
    """Everything a kernel depends on: its cache key is the hash of this."""

    geometry: PressGeometry = PressGeometry()
    material: Material = Material()
    settings: SolverSettings = SolverSettings(element_mm=0.5)
    offsets_mm: tuple[float, ...] = DEFAULT_OFFSETS_MM

    def key(self) -> str:
        text = json.dumps({"format": KERNEL_FORMAT, **asdict(self)}, sort_keys=True, default=float)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    @classmethod
    def for_layout(cls, layout, probe_radius_mm: float = 2.75, **kwargs) -> KernelSpec:
        """The spec of a layout's channels (all must share one cross-section) under a probe of this radius."""
        widths = {c.width_mm for c in layout.channels}
        heights = {c.height_mm for c in layout.channels}
        if len(widths) != 1 or len(heights) != 1:
            raise ValueError(
                f"layout '{layout.name}' has channels of several cross-sections ({sorted(widths)} x "
                f"{sorted(heights)} mm): one kernel covers one cross-section"
            )
        geometry = PressGeometry(
            thickness_mm=layout.thickness_mm,
            channel_width_mm=widths.pop(),
            channel_height_mm=heights.pop(),
            channel_depth_mm=layout.channel_depth_mm,
            probe_radius_mm=probe_radius_mm,
        )
        return cls(geometry=geometry, **kwargs)


@dataclass(frozen=True, eq=False)
class PinchKernel:
    """A/A0 on a regular (offset, depth) grid; nan where the solve did not reach, filled by the last solved depth."""

    offsets_mm: np.ndarray  # (n_o,), from 0, evenly spaced
    depths_mm: np.ndarray  # (n_d,), from 0, evenly spaced
    area_ratio: np.ndarray  # (n_o, n_d), as solved (nan where not reached)
    force_n: np.ndarray  # (n_o, n_d), quasi-3D probe force
    key: str
    provenance: str  # JSON
    extra: dict[str, np.ndarray] | None = None  # (n_o, n_d) columns beside these: the plane-strain table, the hosts

    def __post_init__(self) -> None:
        filled = fill_unsolved(self.area_ratio)
        object.__setattr__(self, "_table", np.clip(filled, 0.0, 1.0))
        object.__setattr__(self, "_table_t", np.ascontiguousarray(self._table.T))  # type: ignore[attr-defined]
        object.__setattr__(self, "_step", (float(self.offsets_mm[1]), float(self.depths_mm[1])))

    def scaled(self, factor: float) -> PinchKernel:
        """This kernel with its pinch 1 - A/A0 times `factor` >= 0, clipped to [0, 1] (1: the same kernel; 0: no
        pinch anywhere; above 1 a channel shuts sooner). A deliberately wrong skin for a negative control; the
        key and provenance say so, and the force is left as solved."""
        if not (np.isfinite(factor) and factor >= 0):
            raise ValueError(f"a pinch scale must be a number >= 0, got {factor!r}")
        if factor == 1.0:  # exactly this kernel: 1 - (1 - a) would move a's last bit
            return self
        pinch = 1.0 - np.clip(self.area_ratio, 0.0, 1.0)  # nan (not reached) stays nan, filled as for this kernel
        ratio = 1.0 - np.clip(factor * pinch, 0.0, 1.0)
        provenance = json.dumps({**json.loads(self.provenance or "{}"), "pinch_scale": float(factor)})
        return PinchKernel(self.offsets_mm, self.depths_mm, ratio, self.force_n, f"{self.key}*{factor:g}", provenance)

    def ratio(self, offset_mm, depth_mm) -> np.ndarray:
        """A/A0 at (offset, depth), broadcast; bilinear. 1 beyond the largest offset and at depth <= 0; the
        deepest row beyond the deepest depth. Shut (0) where the interpolated ratio is below SHUT_AREA_RATIO.
        The same two steps the fe-kernel channel integral takes (skin/kernelpinch.py): the table's row at each
        depth (`depth_rows`), then the offset's place in it (`offset_index`, `lerp_rows`)."""
        offset, depth = np.broadcast_arrays(np.asarray(offset_mm, float), np.asarray(depth_mm, float))
        rows = self.depth_rows(depth.ravel())
        lo, weight = self.offset_index(offset.ravel())
        return self.lerp_rows(rows, lo, weight, np.arange(offset.size)).reshape(offset.shape)

    def depth_rows(self, depth_mm) -> np.ndarray:
        """(n, offsets + 2): A/A0 at every tabulated offset for each of n depths (linear in depth; the deepest
        row beyond the deepest depth; all 1 at depth <= 0), then two columns of 1 that `offset_index` points an
        offset beyond the kernel's reach at. One row per press state: the 48 nodes x channels of a press only
        differ in offset, so the depth is interpolated once per state, not once per node."""
        depth = np.asarray(depth_mm, float).ravel()
        table_t: np.ndarray = self._table_t  # type: ignore[attr-defined]
        n_d = table_t.shape[0]
        fd = np.clip(depth / self._step[1], 0.0, n_d - 1.0)  # type: ignore[attr-defined]
        jd = np.minimum(fd.astype(np.intp), n_d - 2)
        td = (fd - jd)[:, None]
        rows = np.ones((depth.size, table_t.shape[1] + 2))
        rows[:, :-2] = table_t[jd] * (1 - td) + table_t[jd + 1] * td
        rows[depth <= 0, :-2] = 1.0
        return rows

    def offset_index(self, offset_mm) -> tuple[np.ndarray, np.ndarray]:
        """(lower grid index, weight of the next) of each |offset| in a `depth_rows` row; an offset beyond the
        largest tabulated one points at the rows' two trailing 1s with weight 0 (A/A0 = 1 exactly)."""
        offset = np.abs(np.asarray(offset_mm, float))
        n_o = self.offsets_mm.size
        fo = np.minimum(offset / self._step[0], n_o - 1.0)  # type: ignore[attr-defined]
        lo = np.minimum(fo.astype(np.intp), n_o - 2)
        weight = fo - lo
        beyond = offset > self.offsets_mm[-1]
        lo[beyond], weight[beyond] = n_o, 0.0
        return lo, weight

    @staticmethod
    def lerp_rows(rows: np.ndarray, lo: np.ndarray, weight: np.ndarray, row_of=None) -> np.ndarray:
        """A/A0 at (lo, weight) of `offset_index` in `depth_rows` rows, 0 where below SHUT_AREA_RATIO (shut).
        row_of None: every row at every offset, shape (rows, *lo.shape) (one press's states at its nodes);
        else the row of each offset, broadcast with lo and weight."""
        if row_of is None:
            low, high = rows[:, lo], rows[:, lo + 1]
        else:
            flat = rows.ravel()
            at = np.asarray(row_of) * rows.shape[1] + lo
            low, high = flat[at], flat[at + 1]
        value = low * (1 - weight) + high * weight
        return np.where(value < SHUT_AREA_RATIO, 0.0, value)

    @staticmethod
    def lerp_rows_means(rows: np.ndarray, lo: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mean of 1 / A/A0, mean of A/A0) over the last axis of `lerp_rows(rows, lo, weight)`, each
        (rows, *lo.shape[:-1]): a channel's midpoint-rule factor and area at every state.

        The same bits as the means of `lerp_rows` (tested), in two scratch arrays (skin/scratch.py) instead of six
        fresh ones, whose page faults cost as much as the arithmetic. Laid out as `rows[:, lo]` lays out its result
        (rows innermost), so each mean adds the nodes in the same order, one after the other."""
        shape = (*lo.shape, rows.shape[0])  # (..., nodes, rows): rows[:, lo]'s memory order
        value, other = arrays(shape, shape)
        rows_t = np.ascontiguousarray(rows.T)
        np.take(rows_t, lo, axis=0, out=value)  # rows[:, lo]
        np.take(rows_t, lo + 1, axis=0, out=other)
        value *= (1 - weight)[..., None]
        other *= weight[..., None]
        value += other  # low * (1 - weight) + high * weight
        np.copyto(value, 0.0, where=value < SHUT_AREA_RATIO)  # shut
        with np.errstate(divide="ignore"):
            np.divide(1.0, value, out=other)
        n = lo.shape[-1]
        inverse, mean = np.add.reduce(other, axis=-2), np.add.reduce(value, axis=-2)  # np.mean: the sum, then / n
        return np.moveaxis(inverse / n, -1, 0), np.moveaxis(mean / n, -1, 0)


_PROVENANCE_SPEC = ("geometry", "material", "settings")


def _solve_task(spec: KernelSpec, task):
    """One solve of the kernel: ("channel", offset) in plane strain, or ("host", axisymmetric) without a channel."""
    from neatskin.skin.mechanics import solve_press  # the solver (scipy.sparse, scikit-fem) only when computing

    kind, value = task
    if kind == "channel":
        return task, solve_press(spec.geometry, spec.material, spec.settings, value)
    return task, solve_press(
        spec.geometry, spec.material, spec.settings, 0.0, channel=False, axisymmetric=value, bands_mm=spec.offsets_mm
    )


def plane_strain_rows(kernel: PinchKernel, spec: KernelSpec) -> tuple[np.ndarray, np.ndarray, dict]:
    """(A/A0, chord force, provenance) of the plane-strain channel solves inside a kernel file (the quasi-3D
    kernel's `area_ratio_plane_strain`, or a format-1 kernel's `area_ratio`), checked to be of this spec."""
    provenance = json.loads(kernel.provenance or "{}")
    mine = json.loads(json.dumps({k: v for k, v in asdict(spec).items() if k in _PROVENANCE_SPEC}, default=float))
    theirs = {k: provenance.get(k) for k in _PROVENANCE_SPEC}
    if theirs != mine or not np.allclose(kernel.offsets_mm, spec.offsets_mm, rtol=0, atol=1e-9):
        raise ValueError("the plane-strain rows given were solved for another spec (geometry, material, settings)")
    extra = kernel.extra or {}
    area = extra.get("area_ratio_plane_strain", kernel.area_ratio)
    ps = provenance.get("plane_strain", provenance)
    return area, kernel.force_n, {k: ps[k] for k in ("elements", "newton_iterations", "max_volume_change")}


def compute_kernel(spec: KernelSpec, n_jobs: int = 2, progress=None, plane_strain=None) -> PinchKernel:
    """Solve the press at every offset of the spec in plane strain and the intact skin under the strip and the
    round probe (in parallel), and carry the channel kernel onto the round probe (skin/quasi3d.py).
    `plane_strain` (A/A0, chord force, provenance) of this spec (`plane_strain_rows`) skips the channel solves."""
    from joblib import delayed

    from neatskin import __version__
    from neatskin.orphans import watched_parallel
    from neatskin.skin.quasi3d import band_average, local_spread, transfer

    tasks: list[tuple[str, float | bool]] = [("host", False), ("host", True)]
    if plane_strain is None:
        tasks += [("channel", float(o)) for o in spec.offsets_mm]
    # workers that end with this process: killed outright (SIGKILL, OOM), it leaves no solve running for nobody
    run = watched_parallel(n_jobs, return_as="generator")
    solved = {}
    for task, result in run(delayed(_solve_task)(spec, t) for t in tasks):
        solved[task] = result
        if progress is not None:
            progress(1)
    host_ps, host_ax = solved[("host", False)], solved[("host", True)]
    depths = host_ax.depth_mm
    if plane_strain is None:
        results = [solved[("channel", float(o))] for o in spec.offsets_mm]
        area_ps = np.stack([r.area_ratio for r in results])
        force = np.stack([r.chord_force_n for r in results])
        ps_info = {
            "elements": [r.n_elements for r in results],
            "newton_iterations": int(sum(r.newton_iterations for r in results)),
            "max_volume_change": float(np.nanmax(np.abs(np.stack([r.volume_change for r in results])))),
        }
    else:
        area_ps, force, ps_info = plane_strain
    area, d_star = transfer(area_ps, host_ps.strain_eq, host_ax.strain_eq, depths)
    step = max(1, int(round(SPREAD_MM / float(spec.offsets_mm[1] - spec.offsets_mm[0])))) if len(area) > 1 else 1
    spread = local_spread(area_ps, host_ps.strain_eq, host_ax.strain_eq, depths, step, d_star)
    width = spec.geometry.channel_width_mm

    def closing(r, axisymmetric):
        return band_average(r.line_x_mm, r.closing_mm, spec.offsets_mm, width, axisymmetric).T

    extra = {
        "area_ratio_plane_strain": area_ps,
        "matched_depth_mm": d_star,
        "area_ratio_spread": spread,
        "strain_eq_plane_strain": host_ps.strain_eq.T,
        "strain_eq_axisymmetric": host_ax.strain_eq.T,
        "closing_plane_strain_mm": closing(host_ps, False),
        "closing_axisymmetric_mm": closing(host_ax, True),
        "force_axisymmetric_n": np.broadcast_to(host_ax.force_n_per_mm, area.shape).copy(),
    }
    provenance = {
        "kernel_format": KERNEL_FORMAT,
        "key": spec.key(),
        **{k: v for k, v in asdict(spec).items() if k != "offsets_mm"},
        "plane_strain": ps_info,
        "hosts": {
            "elements": [host_ps.n_elements, host_ax.n_elements],
            "newton_iterations": [host_ps.newton_iterations, host_ax.newton_iterations],
        },
        "formulation": "quasi-3D: plane-strain channel kernel, axisymmetric host transfer. The channel: plane strain "
        "across it, mixed u-p Taylor-Hood P2/P1, neo-Hookean, Newton with load steps; bonded flat probe with a "
        "rounded rim; roof-floor penalty contact; open channel (no fluid pressure). The transfer: at distance r "
        "from the round probe's axis and depth d, A/A0 of the strip at offset r and the depth d* where the intact "
        "skin's band-averaged equivalent strain under the strip equals the round probe's (axisymmetric solve)",
        "software": f"neatskin {__version__}, scikit-fem {_version('scikit-fem')}, scipy {_version('scipy')}",
        "force": "force_n: the strip's reaction per mm spread over the round probe's chords (quasi-3D); "
        "force_axisymmetric_n: the round probe on the intact skin (axisymmetric, 3D)",
    }
    return PinchKernel(
        np.asarray(spec.offsets_mm, float), depths, area, force, spec.key(), json.dumps(provenance), extra
    )


def _version(dist: str) -> str:
    from importlib.metadata import version

    return version(dist)


def write_kernel(kernel: PinchKernel, path: Path) -> Path:
    import pyarrow as pa
    import pyarrow.parquet as pq

    o, d = np.meshgrid(kernel.offsets_mm, kernel.depths_mm, indexing="ij")
    table = pa.table(
        {
            "offset_mm": o.ravel(),
            "depth_mm": d.ravel(),
            "area_ratio": kernel.area_ratio.ravel(),
            "force_n": kernel.force_n.ravel(),
            "solved": np.isfinite(kernel.area_ratio.ravel()),
            **{name: np.asarray(column, float).ravel() for name, column in (kernel.extra or {}).items()},
        }
    )
    meta = {b"neatskin.kernel_key": kernel.key.encode(), b"neatskin.provenance": kernel.provenance.encode()}
    path.parent.mkdir(parents=True, exist_ok=True)
    # a new file renamed into place: a reader never sees half a kernel, and a rewritten one is another inode, which
    # read_kernel_once reads again
    staging = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    pq.write_table(table.replace_schema_metadata(meta), staging)
    os.replace(staging, path)
    return path


def read_kernel(path: Path) -> PinchKernel:
    import pyarrow.parquet as pq

    # one file: ParquetFile reads it without pq.read_table's dataset layer, whose import pulls in pandas
    table = pq.ParquetFile(path).read()
    meta = table.schema.metadata or {}
    cols = {name: _column(table, name) for name in ("offset_mm", "depth_mm", "area_ratio", "force_n")}
    offsets, depths = np.unique(cols["offset_mm"]), np.unique(cols["depth_mm"])
    shape = (offsets.size, depths.size)
    extra = {
        name: _column(table, name).astype(float).reshape(shape)
        for name in table.column_names
        if name not in (*cols, "solved")
    }
    return PinchKernel(
        offsets,
        depths,
        cols["area_ratio"].reshape(shape),
        cols["force_n"].reshape(shape),
        meta.get(b"neatskin.kernel_key", b"").decode(),
        meta.get(b"neatskin.provenance", b"{}").decode(),
        extra or None,
    )


def read_kernel_once(path: Path) -> PinchKernel:
    """read_kernel, once per version of the file in this process (the paper kernel: 35 to 60 ms the first read with
    pyarrow.parquet's import, 1 to 14 ms a repeat at load 7): `campaign check`
    and the rails forecast ask whether the kernel is there (railcheck.missing_kernel) and then draw the presses
    with it, and a dry run's rails warning, its skin and its physical limit each load it. A file rewritten (by
    `skin mechanics`, or by hand) has another inode, size or change time and is read again. The kernel's arrays
    are made read-only: every caller shares them."""
    st = path.stat()
    return _read_kernel_version(str(path.resolve()), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


@functools.lru_cache(maxsize=4)
def _read_kernel_version(path: str, *version: int) -> PinchKernel:
    kernel = read_kernel(Path(path))
    for array in (
        kernel.offsets_mm,
        kernel.depths_mm,
        kernel.area_ratio,
        kernel.force_n,
        *(kernel.extra or {}).values(),
    ):
        array.setflags(write=False)
    return kernel


def _column(table, name: str) -> np.ndarray:
    """A column as a numpy array of its own. A float64 column without nulls (every column the kernel writes) is
    copied from its data buffer: pyarrow's to_numpy imports pandas to ask about the type (0.3 s of a dry run's
    start, in the main process and in the skin worker)."""
    import pyarrow as pa

    column = table.column(name).combine_chunks()
    if column.type == pa.float64() and column.null_count == 0:
        return np.frombuffer(column.buffers()[1], np.float64, len(column), column.offset * 8).copy()
    return column.to_numpy(zero_copy_only=False)


def cache_dir() -> Path:
    """$NEATSKIN_CACHE, else $XDG_CACHE_HOME/neatskin, else ~/.cache/neatskin."""
    if os.environ.get("NEATSKIN_CACHE"):
        return Path(os.environ["NEATSKIN_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "neatskin"


def packaged_kernel_path() -> Path:
    from importlib.resources import files

    return Path(str(files("neatskin") / "protocols" / "skins" / PAPER_KERNEL))


def solve_notice() -> str:
    """What a command says before it solves a missing kernel (`load_kernel(..., compute=False)` raised): why nothing
    comes for minutes, and where the result goes."""
    return (
        "first solving the finite-element pinch kernel of this skin and probe (minutes of CPU, once: cached in "
        f"{cache_dir() / 'kernels'})"
    )


def load_kernel(spec: KernelSpec, compute: bool = True, n_jobs: int = 2) -> PinchKernel:
    """The kernel of a spec: the packaged paper kernel if its key matches, else the user cache, else (compute)
    solve it once and cache it. compute=False raises FileNotFoundError instead of solving."""
    key = spec.key()
    packaged = packaged_kernel_path()
    if packaged.exists():
        kernel = read_kernel_once(packaged)
        if kernel.key == key:
            return kernel
    cached = cache_dir() / "kernels" / f"{key}.parquet"
    if cached.exists():
        return read_kernel_once(cached)
    if not compute:
        raise FileNotFoundError(f"no pinch kernel {key} packaged or in {cached.parent}: run `neatskin skin mechanics`")
    kernel = compute_kernel(spec, n_jobs=n_jobs)
    write_kernel(kernel, cached)
    return kernel
