"""Every figure of the docs is redrawn from recorded results by `benchmarks/figures.py`.

The table `figures.FIGURES` names each figure, its results in `benchmarks/results/` and the
function that draws it. Here: every PNG the docs reference is in it (or is a file a qdrl
command writes at run time), every results file it names exists, and each drawing
function redraws (one figure per function, the rest checked by the table only, so the
file takes seconds).
"""

from __future__ import annotations

import inspect
import re
import struct
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
try:
    import figures
finally:
    sys.path.remove(str(ROOT / "benchmarks"))

# PNGs the docs mention that are not docs figures: files a qdrl command writes at run time
# into its own output directory (the docs describe what a run, a report or a render writes).
RUN_TIME_OUTPUTS = {
    "plots/*.png",  # qdrl run: one learning-curve plot per metric
    "plots/summary.png",  # qdrl run: the run in one figure
    "summary.png",  # the README's list of what `qdrl run default` leaves in plots/
    "plots/archive.png",  # qdrl run of an RL / skills agent: its passive archive
    "plots/repertoire.png",  # qdrl run of a QD algorithm: the repertoire's heatmap
    "plots/population.png",  # qdrl run of PBT: the population's members
    "plots/skills.png",  # qdrl run of a skill-discovery agent: each skill's trajectories
    "plots/profiles.png",  # qdrl run of QDAC or UVFA: distance and performance profiles
    "plots/fitness_histogram.png",  # qdrl run of a QD algorithm: its elites' fitnesses
    "plots/fitness_ecdf.png",  # the same as an empirical CDF
    "plots/parallel_axes.png",  # the same for descriptors of more than two dimensions
    "plots/learnt_descriptors.png",  # qdrl run of AURORA: its autoencoder loss, elites and threshold
    "plots/replay_skills.png",  # qdrl render RUN: every skill's path
    "plots/replay_skill3.png",  # qdrl render RUN --skill 3
    "plots/replay_agent.png",  # qdrl render RUN of an RL agent: its first evaluation episode
    "path.png",  # qdrl render RUN --cell 17 --out path.png
    "<task>/<metric>.png",  # qdrl report: one figure per metric and task
    "<task>/repertoires.png",  # qdrl report: the final repertoires
    "<task>/adaptation.png",  # qdrl report of adapted runs: best return per perturbation
    "adaptation.png",  # qdrl adapt RUN: the run's adaptation curves
}
# Figures whose results were never recorded in the repository: kept in the table with the
# reason, not redrawn. A new one belongs here only once its results cannot be kept.
UNRECORDED = {
    "report_arm_qd_score",
    "report_arm_repertoires",
    "skills_point_maze_diayn",
    "skills_point_maze_smerl",
    "me_pbt_vs_map_elites_halfcheetah_uni",
}
_IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+\.png)\)")
_MENTION = re.compile(r"[\w./<>*-]*\.png")


def _docs() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    width, height = struct.unpack(">II", data[16:24])
    return width, height


def test_every_png_the_docs_reference_is_in_the_table_or_a_run_time_output() -> None:
    table = {f.path for f in figures.FIGURES}
    table_names = {Path(path).name for path in table}
    images, unknown, mentioned = set(), [], set()
    for md in _docs():
        text = md.read_text()
        mentioned |= set(_MENTION.findall(text))
        for link in _IMAGE.findall(text):
            path = (md.parent / link).resolve().relative_to(ROOT).as_posix()
            images.add(path)
            assert path in table, f"{md.relative_to(ROOT)}: {link} is not in benchmarks/figures.py"
        for mention in _MENTION.findall(text):
            # a docs figure named in the text rather than shown is a table entry too
            if mention not in RUN_TIME_OUTPUTS and Path(mention).name not in table_names:
                unknown.append(f"{md.relative_to(ROOT)}: {mention}")
    assert not unknown, f"PNGs neither in benchmarks/figures.py nor in RUN_TIME_OUTPUTS: {unknown}"
    assert "docs/report_arm_qd_score.png" in images  # the parsing found the README's figure
    assert sorted(RUN_TIME_OUTPUTS - mentioned) == []  # the list holds only what the docs name


def test_every_figure_file_of_the_docs_is_in_the_table() -> None:
    # none lies in docs/ (or next to the results) without a way to redraw it, or the reason why not
    table = {f.path for f in figures.FIGURES}
    files = [p.relative_to(ROOT).as_posix() for d in ("docs", "benchmarks/results") for p in (ROOT / d).glob("*.png")]
    assert sorted(set(files) - table) == []
    assert sorted(table - set(files)) == []  # and every entry's file is there


def test_every_entry_names_existing_results_and_a_drawing_function_that_takes_them() -> None:
    assert {f.name for f in figures.FIGURES if not f.redrawable} == UNRECORDED
    for f in figures.FIGURES:
        func = figures.drawing_function(f)
        assert callable(func), f.draw
        assert f.recorded_by, f.name
        if not f.redrawable:
            assert not f.results, f"{f.name}: unrecorded, yet results named: {f.results}"
            continue
        assert f.results, f.name
        for r in f.results:
            assert r.startswith("benchmarks/results/") and (ROOT / r).is_file(), f"{f.name}: {r}"
        # the call the redraw makes binds: the loaded results, the table's arguments and the path
        inspect.signature(func).bind(*f.results, **f.args, path="out.png")


def test_one_figure_of_each_drawing_function_redraws(tmp_path: Path) -> None:
    firsts: dict[str, figures.Figure] = {}
    for f in figures.FIGURES:
        if f.redrawable:
            firsts.setdefault(f.draw, f)
    assert len(firsts) >= 5
    for draw, f in firsts.items():
        out = figures.redraw(f, tmp_path / Path(f.path).name)
        assert out.stat().st_size > 0, draw
        # the layout the docs show: the same pixel size as the figure in the repository
        assert _png_size(out) == _png_size(ROOT / f.path), draw


def test_the_command_lists_redraws_some_and_reports_the_unrecorded(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert figures.main(["--list"]) == 0
    listed = capsys.readouterr().out
    assert all(f.path in listed for f in figures.FIGURES)
    assert listed.count("NOT RECORDED") == len(UNRECORDED) and all(n in listed for n in UNRECORDED)

    assert figures.main(["--only", "sac_halfcheetah_eval_return", "--out", str(tmp_path)]) == 0
    assert [p.name for p in tmp_path.iterdir()] == ["sac_halfcheetah_eval_return.png"]
    capsys.readouterr()
    # asked for by name, an unrecorded figure is refused with its reason, not skipped silently
    assert figures.main(["--only", "report_arm_qd_score", "--out", str(tmp_path)]) == 1
    assert "NOT REDRAWN docs/report_arm_qd_score.png" in capsys.readouterr().err
    assert len(list(tmp_path.iterdir())) == 1
