"""The pinch kernel (skin/kernel.py) and the "fe-kernel" deformation model (skin/kernelpinch.py, SkinModel(kernel=)):
interpolation, file round trip, content-keyed cache, exact scalings, cut electrodes, volume conservation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from neatskin.layout import load_layout
from neatskin.skin import kernel as kmod
from neatskin.skin.kernel import KernelSpec, Material, PinchKernel, read_kernel, write_kernel
from neatskin.skin.kernelpinch import kernel_factor_and_share
from neatskin.skin.model import SkinModel
from neatskin.skin.network import equivalent_resistance

LAYOUT = load_layout("protocols/skins/paper.toml")


def _kernel(table, offsets, depths, key="test"):
    return PinchKernel(
        np.asarray(offsets, float), np.asarray(depths, float), np.asarray(table, float), np.zeros_like(table), key, "{}"
    )


def _smooth_kernel(reach=10.0):
    offsets, depths = np.arange(0, reach + 1e-9, 0.5), np.arange(0, 4.51, 0.25)
    o, d = np.meshgrid(offsets, depths, indexing="ij")
    return _kernel(1 - 0.8 * (d / 4.5) * np.exp(-((o / 4.0) ** 2)), offsets, depths)


def test_interpolation_is_exact_on_the_grid_bilinear_between_and_symmetric():
    k = _smooth_kernel()
    o, d = np.meshgrid(k.offsets_mm, k.depths_mm, indexing="ij")
    assert np.array_equal(k.ratio(o, d), np.where(k.area_ratio < 0.02, 0.0, k.area_ratio))
    mid = k.ratio(0.25, 1.125)  # the mean of the four corners
    assert mid == pytest.approx(k.area_ratio[:2, 4:6].mean(), rel=1e-12)
    assert np.array_equal(k.ratio(-3.3, 2.0), k.ratio(3.3, 2.0))
    assert k.ratio(10.01, 3.0) == 1.0 and k.ratio(2.0, 0.0) == 1.0 and k.ratio(2.0, -1.0) == 1.0
    assert k.ratio(0.0, 9.0) == k.ratio(0.0, 4.5)  # deeper than solved: the deepest row


def test_unsolved_depths_take_the_last_solved_value_and_tiny_ratios_are_shut():
    table = np.array([[1.0, 0.5, 0.01, np.nan], [1.0, 0.9, 0.8, np.nan]])
    k = _kernel(table, [0.0, 0.5], [0.0, 1.0, 2.0, 3.0])
    assert k.ratio(0.5, 3.0) == pytest.approx(0.8)
    assert k.ratio(0.0, 3.0) == 0.0  # 0.01 < SHUT_AREA_RATIO


def test_kernel_file_round_trip_keeps_values_key_and_provenance(tmp_path):
    k = _smooth_kernel()
    path = write_kernel(k, tmp_path / "k.parquet")
    back = read_kernel(path)
    assert np.array_equal(back.area_ratio, k.area_ratio) and np.array_equal(back.depths_mm, k.depths_mm)
    assert back.key == "test" and json.loads(back.provenance) == {}


def test_the_cache_key_follows_the_content_and_a_cached_kernel_is_not_recomputed(tmp_path, monkeypatch):
    spec = KernelSpec()
    assert spec.key() == KernelSpec().key()
    assert spec.key() != KernelSpec(material=Material(shear_modulus_mpa=0.03)).key()
    monkeypatch.setenv("NEATSKIN_CACHE", str(tmp_path))
    monkeypatch.setattr(kmod, "packaged_kernel_path", lambda: tmp_path / "none.parquet")
    calls = []

    def fake_compute(s, n_jobs=2):
        calls.append(s.key())
        return _smooth_kernel()

    monkeypatch.setattr(kmod, "compute_kernel", fake_compute)
    with pytest.raises(FileNotFoundError, match="skin mechanics"):
        kmod.load_kernel(spec, compute=False)
    first = kmod.load_kernel(spec)
    second = kmod.load_kernel(spec)
    assert calls == [spec.key()]
    assert (tmp_path / "kernels" / f"{spec.key()}.parquet").exists()
    assert np.array_equal(first.area_ratio, second.area_ratio)


def test_a_uniform_kernel_scales_every_channel_exactly():
    c = 0.625
    offsets, depths = np.arange(0, 100.1, 0.5), np.array([0.0, 1.0, 2.0])
    k = _kernel(np.where(depths[None, :] > 0, c, 1.0) * np.ones((offsets.size, 1)), offsets, depths)
    factor, share = kernel_factor_and_share(LAYOUT, k, [7.5, 20.0], [7.5, 3.0], [1.0, 2.0])
    assert np.allclose(factor, 1 / c, rtol=1e-14) and np.allclose(share, 1 - c, rtol=1e-14)
    model = SkinModel(LAYOUT, kernel=k)
    assert model.deformation == "fe-kernel"
    pressed = model.pair_resistance_ohm(7.5, 7.5, 1.0)[0]
    assert np.allclose(pressed, model.baseline_pair_resistance_ohm / c, rtol=1e-12)


def test_a_press_out_of_reach_or_not_touching_is_the_baseline_exactly():
    model = SkinModel(LAYOUT, kernel=_smooth_kernel(reach=3.0))
    base = model.baseline_pair_resistance_ohm
    assert np.array_equal(model.pair_resistance_ohm(7.5, 7.5, 3.5)[0], base)  # 7.5 mm from every channel
    assert np.array_equal(model.pair_resistance_ohm(15.0, 15.0, 0.0)[0], base)


def test_a_shut_section_cuts_its_channel_and_isolates_a_corner_electrode():
    offsets, depths = np.arange(0, 10.1, 0.5), np.array([0.0, 1.0, 4.0])
    o = offsets[:, None] * np.ones((1, depths.size))
    k = _kernel(np.where((o <= 3.0) & (depths[None, :] > 0), 0.0, 1.0), offsets, depths)
    model = SkinModel(LAYOUT, kernel=k)
    r_channels = model.channel_resistance_ohm(0.0, 0.0, 2.0)[0]  # on the corner junction J00 (electrode 8)
    shut = {c for c, ch in enumerate(LAYOUT.channels) if 0 in (ch.a, ch.b)}
    assert {int(c) for c in np.flatnonzero(np.isinf(r_channels))} == shut
    pairs = model.pair_resistance_ohm(0.0, 0.0, 2.0)[0]
    with_8 = np.array([8 in (p.i, p.j) for p in LAYOUT.pairs])
    assert np.all(np.isinf(pairs[with_8])) and np.all(np.isfinite(pairs[~with_8]))
    conductance = np.where(np.isinf(r_channels), 0.0, 1.0 / r_channels)
    assert np.array_equal(pairs, equivalent_resistance(LAYOUT, conductance[None, :])[0])


def test_the_sealed_network_conserves_the_fluid_volume_with_the_kernel():
    model = SkinModel(LAYOUT, kernel=_smooth_kernel(), displaced_fluid_fraction=1.0)
    x, y, d = np.array([7.5, 15.0, 3.0]), np.array([0.0, 15.0, 11.0]), np.array([3.5, 2.0, 4.0])
    total = model.channel_volume_mm3.sum()
    assert np.allclose(model.channel_fluid_volume_mm3(x, y, d).sum(axis=1), total, rtol=1e-13)
    assert np.all(model.pinched_volume_mm3(x, y, d).sum(axis=1) > 0)
    open_network = SkinModel(LAYOUT, kernel=_smooth_kernel())
    r_sealed, r_open = model.channel_resistance_ohm(x, y, d), open_network.channel_resistance_ohm(x, y, d)
    assert np.all(r_sealed < r_open)  # the kept fluid widens every channel


def test_the_channel_rule_converges():
    k = _smooth_kernel()
    rng = np.random.default_rng(3)
    x, y, d = rng.uniform(-5, 35, 200), rng.uniform(-5, 35, 200), rng.uniform(0.5, 4.0, 200)
    coarse = kernel_factor_and_share(LAYOUT, k, x, y, d)[0]
    fine = kernel_factor_and_share(LAYOUT, k, x, y, d, nodes=960)[0]
    assert np.max(np.abs(coarse / fine - 1)) < 2e-3


def test_the_packaged_paper_kernel_loads_and_matches_its_spec():
    path = kmod.packaged_kernel_path()
    if not path.exists():
        pytest.skip("no packaged kernel")
    kernel = read_kernel(path)
    spec = KernelSpec.for_layout(LAYOUT)
    assert kernel.key == spec.key()
    assert kmod.load_kernel(spec, compute=False).key == kernel.key
    assert kernel.ratio(0.0, 3.5) == 0.0  # under the probe at the paper's depth the channel is shut
    assert 0.5 < kernel.ratio(10.0, 3.5) <= 1.0


def test_the_packaged_kernel_is_what_the_solver_gives():
    from neatskin.skin.mechanics import solve_press

    path = kmod.packaged_kernel_path()
    if not path.exists():
        pytest.skip("no packaged kernel")
    kernel, spec = read_kernel(path), KernelSpec.for_layout(LAYOUT)
    row = int(np.flatnonzero(kernel.offsets_mm == 2.0)[0])
    result = solve_press(spec.geometry, spec.material, spec.settings, 2.0)
    strip = kernel.extra["area_ratio_plane_strain"][row]  # the quasi-3D kernel's plane-strain source row
    assert np.allclose(result.area_ratio, strip, rtol=0, atol=1e-9, equal_nan=True)


def test_skin_mechanics_cli_writes_the_kernel_with_provenance_and_a_plot(tmp_path):
    import pyarrow.parquet as pq

    from neatskin.cli import main

    assert (
        main(
            [
                "skin",
                "mechanics",
                "--out",
                str(tmp_path),
                "--max-offset-mm",
                "0.5",
                "--element-mm",
                "1.0",
                "--jobs",
                "1",
            ]
        )
        == 0
    )
    table = pq.read_table(tmp_path / "pinch_kernel.parquet")
    assert {"offset_mm", "depth_mm", "area_ratio", "force_n", "solved"} <= set(table.column_names)
    assert {"area_ratio_plane_strain", "closing_plane_strain_mm", "closing_axisymmetric_mm"} <= set(table.column_names)
    frame = table.to_pandas()
    assert sorted(frame.offset_mm.unique()) == [0.0, 0.5] and frame.depth_mm.max() == 4.5
    assert frame.loc[frame.depth_mm == 0, "area_ratio"].eq(1.0).all()
    assert (
        frame.loc[frame.depth_mm >= 1.75, "area_ratio"].eq(0.0).all()
    )  # shut under the probe (quasi-3D: 1.5 in the strip)
    provenance = json.loads(table.schema.metadata[b"neatskin.provenance"])
    assert provenance["material"]["shear_modulus_mpa"] == 0.023 and "scikit-fem" in provenance["software"]
    assert provenance["settings"]["element_mm"] == 1.0
    assert provenance["formulation"].startswith("quasi-3D: plane-strain channel kernel, axisymmetric host")
    assert (tmp_path / "pinch_kernel.png").stat().st_size > 10_000
