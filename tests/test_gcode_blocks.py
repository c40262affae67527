"""Press blocks made on demand (gcode.blocks): the G-code is the stored program's byte for byte, views select
presses without copying text, and a 28,000-press plan's memory does not grow with its G-code text."""

import hashlib
import os
import pickle
import shutil
import sys
import tracemalloc

import numpy as np
import pytest
from conftest import PROTOCOLS

from neatskin.errors import ConfigError
from neatskin.gcode import emit
from neatskin.gcode.blocks import PressBlock, PressBlocks
from neatskin.gcode.positions import PositionSpec, generate_positions
from neatskin.gcode.profile import load_printer_profile
from neatskin.gcode.program import PressSpec, build_program
from neatskin.gcode.spec import build_from_protocol
from neatskin.rig.plan import build_plan
from neatskin.rig.protocol import load_protocol

# sha256 of "\n".join(command_lines()) of protocols/paper.toml's program, as 98085f2 (which stored every
# press's lines) produced it: the lines made on demand must be the same bytes. Changed once since, on purpose: the
# preamble's G28 became G28 R15.5 (Z raised by the surface + safe height before homing); a diff of the two
# programs' lines shows that line, the 4th, as the only difference
PAPER_COMMANDS_SHA256 = {
    False: "2bf4ab56aa5152bde1659552e2f53ff7e9e89932ccc00cc93cddcdcba6dcb32d",  # the runner's (no G4 hold)
    True: "f8960fc0b68ca08336dc749f62b9ef24a6af7d173fb838a0b02226d0245f0946",  # a file's (G4 P1200 hold)
}


# this module's, made once per worker (module scope remade it whenever the suite's order came back to it)
@pytest.fixture(scope="session")
def program(paper_layout):
    profile = load_printer_profile(PROTOCOLS / "printers" / "paper.toml")
    positions = generate_positions(paper_layout, PositionSpec("paper", 6, 3))
    return build_program(
        paper_layout, positions, PressSpec(depth_mm=3.5, repeats=3, order="shuffled", hold_s=0.5), profile, seed=2
    )


@pytest.mark.parametrize("hold", [False, True])
def test_paper_program_commands_are_the_stored_programs_bytes(hold):
    program, _, _ = build_from_protocol(PROTOCOLS / "paper.toml", hold_in_gcode=hold)
    text = "\n".join(program.command_lines())
    assert len(program.presses) == 2800
    assert hashlib.sha256(text.encode()).hexdigest() == PAPER_COMMANDS_SHA256[hold]


def test_indexing_iteration_and_slices_give_the_same_blocks(program):
    blocks = list(program.presses)
    assert len(blocks) == len(program.presses) == 18
    assert [b.press_id for b in blocks] == list(range(18))
    assert all(program.presses[k] == blocks[k] for k in range(18))
    assert program.presses[-3] == blocks[15]
    assert list(program.presses[4:10:2]) == blocks[4:10:2]
    assert program.presses[4:10] == blocks[4:10]  # a view equals the tuple it replaces, element by element
    assert program.presses != blocks[:17]
    assert [b.position_id for b in blocks] == program.presses.position_ids.tolist()
    with pytest.raises(IndexError):
        program.presses[18]
    with pytest.raises(IndexError):
        program.presses[-19]


def test_excluding_keeps_order_and_the_last_block_is_the_one_iteration_yields(program):
    todo = program.presses.excluding({0, 5, 17})
    assert todo.press_ids.tolist() == [k for k in range(18) if k not in (0, 5, 17)]
    yielded = list(todo)
    assert yielded[-1] is todo[-1]  # the runner's `block is not todo[-1]`: no checkpoint after the last press
    assert yielded[0] is not todo[-1]
    assert [b.press_id for b in todo[:4]] == [1, 2, 3, 4]
    head = todo[:4]
    assert head[-1] is list(head)[-1]
    assert len(program.presses.excluding(range(18))) == 0
    assert list(program.presses.excluding(set())) == list(program.presses)


def test_blocks_pickle_and_compare_by_content(program, paper_layout):
    again = pickle.loads(pickle.dumps(program.presses))
    assert isinstance(again, PressBlocks) and again == program.presses
    assert list(again) == list(program.presses)
    block = program.presses[7]
    assert isinstance(block, PressBlock) and pickle.loads(pickle.dumps(block)) == block
    other = build_program(
        paper_layout,
        program.positions,
        PressSpec(repeats=3, order="shuffled", hold_s=0.5, depth_mm=3.0),
        load_printer_profile(PROTOCOLS / "printers" / "paper.toml"),
        seed=2,
    )
    assert other.presses != program.presses  # same ids and targets, another press depth: other lines
    assert other.presses[3].phase("press").lines != program.presses[3].phase("press").lines


@pytest.mark.slow
def test_a_28000_press_plan_does_not_hold_its_gcode_text(tmp_path):
    """A plan holds a few numbers per press, not its ~1.7 kB of G-code text: building a 28,000-press plan peaks
    (tracemalloc) below 8 MB. 98085f2, which stored every block's lines, held 46 MB after building it."""
    for sub in ("skins", "wiring", "printers"):
        shutil.copytree(PROTOCOLS / sub, tmp_path / sub)
    path = tmp_path / "paper-28000.toml"
    path.write_text((PROTOCOLS / "paper.toml").read_text().replace("count = 100", "count = 1000"))
    protocol = load_protocol(path)
    tracemalloc.start()
    try:
        plan = build_plan(protocol)
        held, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert plan.n_presses == 28000
    stored_mb = sum(sys.getsizeof(line) for block in plan.program.presses for p in block.phases for line in p.lines)
    assert stored_mb / 2**20 > 20  # the lines alone as str objects (98085f2 held them: 46 MB with the tuples)
    assert peak < 8 * 2**20, f"building the plan peaked at {peak / 2**20:.1f} MB"
    assert held < 4 * 2**20, f"the plan holds {held / 2**20:.1f} MB"
    assert np.array_equal(plan.program.presses.position_ids, np.repeat(np.arange(1000), 28))


def test_write_lines_atomic_writes_the_program_text_block_by_block(program, tmp_path, monkeypatch):
    monkeypatch.setattr(emit, "WRITE_BLOCK_LINES", 7)  # several blocks and a partial last one
    out = tmp_path / "p.gcode"
    written = emit.write_lines_atomic(out, emit.program_lines(program), "ascii", "--output")
    assert out.read_bytes() == program.text().encode("ascii")
    assert (
        written == program.text().count("\n") == 18 * 14 + 19
    )  # a comment and 13 commands a press; 7 header lines, 5 + 5 commands, 2 comments


def test_write_lines_atomic_leaves_the_old_file_when_a_later_block_fails(tmp_path):
    out = tmp_path / "p.gcode"
    out.write_text("old\n")
    with pytest.raises(ConfigError, match="cannot write 'é' \\(U\\+00E9\\) as ascii") as info:
        emit.write_lines_atomic(out, ["G28"] * (emit.WRITE_BLOCK_LINES + 1) + ["; café"], "ascii", "--output")
    assert info.value.field == "--output"
    assert sorted(os.listdir(tmp_path)) == ["p.gcode"] and out.read_text() == "old\n"
