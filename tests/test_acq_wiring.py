"""The wiring file: the paper board loads, and every technician mistake is refused with its message."""

import re
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from neatskin.acquisition.wiring import load_wiring, sequential_wiring, wiring_layout_path, wiring_to_toml
from neatskin.errors import ConfigError

PAPER = Path(__file__).resolve().parent.parent / "protocols" / "wiring" / "paper.toml"


def test_paper_wiring_routes_pair_p_on_chip_p_div_4(paper_layout):
    w = load_wiring(PAPER, paper_layout)
    assert w.n_chips == 7 and w.n_pairs == 28
    assert w.line_names == tuple(f"port0/line{k}" for k in range(9))
    for p, route in enumerate(w.routes):
        pair = paper_layout.pairs[p]
        assert (route.chip, route.address) == (p // 4, p % 4)
        assert {route.x_electrode, route.y_electrode} == {pair.i, pair.j}
    assert w.routes[27].x_electrode == 7 and w.routes[27].y_electrode == 8
    assert wiring_layout_path(PAPER) == (PAPER.parent / "../skins/paper.toml").resolve()


def _write(tmp_path, text):
    path = tmp_path / "board.toml"
    path.write_text(text)
    return path


def _paper_text(paper_layout):
    return wiring_to_toml(sequential_wiring(paper_layout))


def _refused(tmp_path, paper_layout, text):
    path = _write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_wiring(path, paper_layout)
    for problem in info.value.problems:
        assert problem.file == str(path) and problem.field and problem.fix
    return info.value


def test_round_trip(tmp_path, paper_layout):
    w = sequential_wiring(paper_layout)
    assert load_wiring(_write(tmp_path, _paper_text(paper_layout)), paper_layout).routes == w.routes


def test_electrode_not_in_layout(tmp_path, paper_layout):
    text = _paper_text(paper_layout).replace("X0 = 1, Y0 = 2,", "X0 = 1, Y0 = 9,", 1)
    err = _refused(tmp_path, paper_layout, text)
    assert any("electrode 9 on pin Y0 of chip 'U1' is not in the layout" in str(p) for p in err.problems)
    assert err.problems[0].field == "chips[0].pins.Y0"
    # one mistake, one problem: the half-wired address and the unrouted pair 1-2 follow from it
    assert len(err.problems) == 1


def test_pair_missing(tmp_path, paper_layout):
    text = _paper_text(paper_layout).replace(", X3 = 7, Y3 = 8", "")
    err = _refused(tmp_path, paper_layout, text)
    assert len(err.problems) == 1
    assert "pair 7-8 of S is not routed by any chip" in str(err)


def test_pair_routed_twice(tmp_path, paper_layout):
    # chip U7 address 3 wired to 1-2 instead of 7-8: 1-2 twice, 7-8 missing
    text = _paper_text(paper_layout).replace("X3 = 7, Y3 = 8", "X3 = 2, Y3 = 1")
    err = _refused(tmp_path, paper_layout, text)
    messages = [p.message for p in err.problems]
    assert any(re.search(r"pair 1-2 is routed twice: chip 'U7' address 3 and chips\[0\]", m) for m in messages)
    # one mistake, one problem: the pair left unrouted is named in its fix
    assert len(messages) == 1
    assert err.problems[0].fix.endswith("; pairs not routed by any chip: 7-8")


def test_both_ends_on_one_electrode(tmp_path, paper_layout):
    text = _paper_text(paper_layout).replace("X3 = 7, Y3 = 8", "X3 = 8, Y3 = 8")
    err = _refused(tmp_path, paper_layout, text)
    assert "pair with both ends on electrode 8" in str(err)
    assert err.problems[0].field == "chips[6].pins.X3/Y3"


def test_half_wired_address(tmp_path, paper_layout):
    text = _paper_text(paper_layout).replace(", Y3 = 8", "")
    err = _refused(tmp_path, paper_layout, text)
    assert "address 3 of chip 'U7' has X3 wired but not Y3" in str(err)


def test_two_electrodes_on_one_pin(tmp_path, paper_layout):
    text = _paper_text(paper_layout).replace("X3 = 7, Y3 = 8", "X3 = [7, 6], Y3 = 8")
    err = _refused(tmp_path, paper_layout, text)
    assert "two electrodes on one pin: X3 of chip 'U7' is wired to electrodes 7, 6" in str(err)


def test_unknown_pin(tmp_path, paper_layout):
    text = _paper_text(paper_layout).replace("X3 = 7, Y3 = 8", "X4 = 7, Y4 = 8")
    err = _refused(tmp_path, paper_layout, text)
    assert "chip 'U7' has no pin 'X4'" in str(err)


def test_digital_line_used_twice(tmp_path, paper_layout):
    text = _paper_text(paper_layout).replace('inhibit = "port0/line8"', 'inhibit = "port0/line1"')
    err = _refused(tmp_path, paper_layout, text)
    assert len(err.problems) == 1
    assert err.problems[0].field == "chips[6].inhibit"
    assert "digital line 'port0/line1' is already used by lines.B" in str(err)


def test_malformed_line(tmp_path, paper_layout):
    text = _paper_text(paper_layout).replace('A = "port0/line0"', 'A = "P0.0"')
    err = _refused(tmp_path, paper_layout, text)
    assert "digital line 'P0.0' is not of the form 'portN/lineM'" in str(err)


def test_too_few_chips(tmp_path, paper_layout):
    text = _paper_text(paper_layout)
    text = text[: text.rindex("[[chips]]")]  # drop U7
    err = _refused(tmp_path, paper_layout, text)
    assert "6 chips route at most 24 pairs, the layout has 28" in str(err)
    assert "wire 7 chips (1 more)" in str(err)


def test_not_toml_and_missing_file(tmp_path, paper_layout):
    err = _refused(tmp_path, paper_layout, "[lines\nA=")
    assert "not valid TOML" in str(err)
    with pytest.raises(ConfigError, match="cannot read wiring file"):
        load_wiring(tmp_path / "nope.toml", paper_layout)


def test_pairs_come_from_the_layout(tmp_path, paper_layout):
    # a 4-electrode layout needs 6 pairs -> 2 chips; nothing is hard-coded to 28
    import tomllib

    from neatskin.layout import layout_from_dict

    data = tomllib.loads((PAPER.parent.parent / "skins" / "paper.toml").read_text())
    data["electrodes"] = [e for e in data["electrodes"] if e["number"] in (1, 3, 5, 7)]
    small = layout_from_dict(data)
    w = sequential_wiring(small)
    assert (w.n_chips, w.n_pairs) == (2, 6)
    assert load_wiring(_write(tmp_path, wiring_to_toml(w)), small).routes == w.routes


@settings(max_examples=30, deadline=None)
@given(data=st.data())
def test_any_board_that_routes_every_pair_once_loads_and_sweeps_soundly(tmp_path_factory, paper_layout, data):
    """Shuffle which chip and address carry which pair, and which end sits on X: always valid, always sound."""
    import tomllib

    from neatskin.acquisition.sequence import build_sweep, check_sweep

    n = len(paper_layout.pairs)
    n_chips = data.draw(st.integers(7, 9))
    slots = data.draw(st.permutations(range(4 * n_chips)))[:n]
    swap = data.draw(st.lists(st.booleans(), min_size=n, max_size=n))
    lines = data.draw(st.permutations(range(32)))[: 2 + n_chips]
    chips = [{"name": f"U{c + 1}", "inhibit": f"port0/line{lines[2 + c]}", "pins": {}} for c in range(n_chips)]
    for p, pair in enumerate(paper_layout.pairs):
        c, k = divmod(slots[p], 4)
        x, y = (pair.j, pair.i) if swap[p] else (pair.i, pair.j)
        chips[c]["pins"].update({f"X{k}": x, f"Y{k}": y})

    def pins(d):
        return "{ " + ", ".join(f"{k} = {v}" for k, v in d.items()) + " }"

    text = f'[lines]\nA = "port0/line{lines[0]}"\nB = "port0/line{lines[1]}"\n' + "".join(
        f'\n[[chips]]\nname = "{ch["name"]}"\ninhibit = "{ch["inhibit"]}"\npins = {pins(ch["pins"])}\n' for ch in chips
    )
    tomllib.loads(text)
    path = tmp_path_factory.mktemp("board") / "board.toml"
    path.write_text(text)
    w = load_wiring(path, paper_layout)
    for p, route in enumerate(w.routes):
        assert (route.chip, route.address) == divmod(slots[p], 4)
    for order in ("pairs", "gray"):
        sweep = build_sweep(w, order=order)
        assert check_sweep(sweep) == [] and sorted(sweep.order.tolist()) == list(range(n))


def test_electrical_limits_are_read_and_round_trip(tmp_path, paper_layout):
    w = load_wiring(PAPER, paper_layout)
    assert (w.electrical.supply_positive_v, w.electrical.supply_negative_v) == (8.0, -8.0)
    assert (w.electrical.r_on_ohm, w.electrical.r_on_mismatch_ohm) == (100.0, 10.0)
    text = _paper_text(paper_layout).replace("r_on_ohm = 100.0", "r_on_ohm = 45.0")
    again = load_wiring(_write(tmp_path, text), paper_layout)
    assert again.electrical.r_on_ohm == 45.0
    assert load_wiring(_write(tmp_path, wiring_to_toml(again)), paper_layout).electrical == again.electrical


@pytest.mark.parametrize(
    "old, new, field, message",
    [
        ("[electrical]", "[electric]", "electric", "unknown table [electric]"),
        ("r_on_ohm = 100.0", "r_on = 100.0", "electrical.r_on", "unknown key 'r_on'"),
        ("supply_negative_v = -8.0", "supply_negative_v = 8.0", "electrical.supply_negative_v", "must be below 0"),
        ('inhibit = "port0/line2"', 'inhibit = "port0/line2"\ninhibitt = 1', "chips[0].inhibitt", "unknown key"),
    ],
)
def test_electrical_and_chip_mistakes_are_named(tmp_path, paper_layout, old, new, field, message):
    text = _paper_text(paper_layout)
    assert old in text
    with pytest.raises(ConfigError) as info:
        load_wiring(_write(tmp_path, text.replace(old, new, 1)), paper_layout)
    assert [p.field for p in info.value.problems] == [field]
    assert message in info.value.problems[0].message and info.value.problems[0].fix
