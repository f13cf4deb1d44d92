"""Bad input, command by command: exit status 2, one line on stderr naming the option, file, field
or value, no traceback, nothing written, and no robot moved (the README's rule, checked on 69
cases across every command of the project).

Every case runs the real command in a subprocess, in an empty working folder; the inputs it needs
lie in a sibling folder. After the run the working folder must still be empty and the outputs the
case names must not exist.
"""

from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from tests.conftest import TINY_WORLD

pytestmark = pytest.mark.slow      # one subprocess per case

#: (id, module, arguments, text that must appear on the one line); "{in}" is the inputs folder,
#: "{map}" the session's tiny map, "{world}" the tiny world, "{out}" a path that must stay unwritten
CASES = [
    # robot.run: the mapping run
    ("map-unknown-world", "robot.run", "--mode map --world nowhere --out {out}", "no world named 'nowhere'"),
    ("map-video-is-a-folder", "robot.run", "--mode map --video {in}/folder --out {out}", "is a folder"),
    ("map-video-missing", "robot.run", "--mode map --video {in}/nope.mp4 --out {out}", "no such video file"),
    ("map-video-not-a-video", "robot.run", "--mode map --video {in}/garbage.mp4 --out {out}", "garbage.mp4"),
    ("map-images-is-a-file", "robot.run", "--mode map --images {in}/file.txt --out {out}", "is a file"),
    ("map-recording-broken-summary", "robot.run", "--mode map --recording {in}/broken_recording",
     "summary.json"),
    ("map-out-is-a-file", "robot.run", "--mode map --world {world} --out {in}/file.txt", "--out"),
    ("map-map-not-a-map-folder", "robot.run", "--mode map --world {world} --out {out} --map {in}/folder",
     "not a map folder"),
    ("map-appearance-seed-negative", "robot.run", "--mode map --world {world} --appearance-seed -1",
     "--appearance-seed"),
    ("map-seed-negative", "robot.run", "--mode map --world {world} --seed -3", "--seed"),
    ("map-every-zero", "robot.run", "--mode map --images {in}/folder --every 0", "--every"),
    ("map-every-s-negative", "robot.run", "--mode map --images {in}/folder --every-s -2", "--every-s"),
    ("map-config-is-a-folder", "robot.run", "--mode map --world {world} --out {out} --config {in}/folder",
     "is a folder"),
    ("map-config-bad-value", "robot.run", "--mode map --world {world} --out {out} --config {in}/sparsity.yaml",
     "mapping.sparsity"),
    ("map-config-unknown-field", "robot.run", "--mode map --world {world} --out {out} --config {in}/typo.yaml",
     "navigation.heading_hint"),
    ("map-config-bad-yaml", "robot.run", "--mode map --world {world} --out {out} --config {in}/garbage.yaml",
     "not valid YAML"),
    ("mode-unknown", "robot.run", "--mode fly", "--mode"),
    # robot.run: navigation in the simulator
    ("navigate-no-map", "robot.run", "--mode navigate --world {world} --route short", "--map"),
    ("navigate-map-missing", "robot.run", "--mode navigate --map {in}/nomap --route short", "no such map folder"),
    ("navigate-map-not-a-map", "robot.run", "--mode navigate --world {world} --map {in}/folder --route short",
     "manifest.json"),
    ("navigate-max-steps-zero", "robot.run", "--mode navigate --world {world} --map {map} --route short "
     "--max-steps 0", "--max-steps"),
    ("navigate-unknown-route", "robot.run", "--mode navigate --world {world} --map {map} --route nosuch",
     "nosuch"),
    ("navigate-unknown-node", "robot.run", "--mode navigate --world {world} --map {map} --goal 9999 "
     "--start short", "9999"),
    ("navigate-negative-node", "robot.run", "--mode navigate --world {world} --map {map} --goal -4 --start short",
     "--goal"),
    ("navigate-goal-image-missing", "robot.run", "--mode navigate --world {world} --map {map} "
     "--goal {in}/nope.jpg --start short", "nope.jpg"),
    ("navigate-goal-image-is-a-folder", "robot.run", "--mode navigate --world {world} --map {map} "
     "--goal {in}/folder --start short", "is a folder"),
    ("navigate-goal-not-an-image", "robot.run", "--mode navigate --world {world} --map {map} "
     "--goal {in}/file.txt --start short", "file.txt"),
    ("navigate-start-off-the-floor", "robot.run", "--mode navigate --world {world} --map {map} --route short "
     "--start 100,100,0", "off the floor"),
    ("navigate-start-in-a-wall", "robot.run", "--mode navigate --world {world} --map {map} --route short "
     "--start 0.05,2,0", "free floor"),
    ("navigate-start-malformed", "robot.run", "--mode navigate --world {world} --map {map} --route short "
     "--start 1,2", "x,y,yaw_deg"),
    ("navigate-result-is-a-folder", "robot.run", "--mode navigate --world {world} --map {map} --route short "
     "--result {in}/folder", "--result"),
    ("navigate-trace-under-a-file", "robot.run", "--mode navigate --world {world} --map {map} --route short "
     "--trace {in}/file.txt/trace.png", "--trace"),
    ("show-no-map", "robot.run", "--mode show", "--map"),
    # robot.run: the real base
    ("serial-port-missing", "robot.run", "--mode navigate --hal serial --map {map} --goal 1 --port /dev/ttyNOPE",
     "/dev/ttyNOPE"),
    ("serial-no-goal", "robot.run", "--mode navigate --hal serial --map {map} --port /dev/ttyNOPE", "--goal"),
    ("serial-max-steps-negative", "robot.run", "--mode navigate --hal serial --map {map} --goal 1 "
     "--port /dev/ttyNOPE --max-steps -5", "--max-steps"),
    ("serial-baud-zero", "robot.run", "--mode navigate --hal serial --map {map} --goal 1 --baud 0", "--baud"),
    # robot.bench
    ("bench-unknown-command", "robot.bench", "fly", "fly"),
    ("vpr-ref-missing", "robot.bench", "vpr --ref {in}/noref --query {in}/folder", "--ref"),
    ("vpr-bad-setting-type", "robot.bench", "vpr --ref {in}/folder --query {in}/folder "
     "--backend effnet-vlad:clusters=abc", "clusters"),
    ("vpr-unknown-backend", "robot.bench", "vpr --ref {in}/folder --query {in}/folder --backend nosuch", "nosuch"),
    ("vpr-json-under-a-file", "robot.bench", "vpr --ref {in}/folder --query {in}/folder --backend tiny "
     "--json {in}/file.txt/x.json", "--json"),
    ("perf-repeats-zero", "robot.bench", "perf --world {world} --repeats 0", "--repeats"),
    ("perf-unknown-engine", "robot.bench", "perf --world {world} --engines onnxruntime,tensorflow", "--engines"),
    ("perf-video-is-a-folder", "robot.bench", "perf --world {world} --video {in}/folder", "--video"),
    ("paper-trials-zero", "robot.bench", "paper --trials 0 --out {out}", "--trials"),
    ("paper-route-without-world", "robot.bench", "paper --routes hospital --out {out}", "WORLD:ROUTE"),
    ("paper-unknown-method", "robot.bench", "paper --methods foo --out {out}", "--methods"),
    ("replay-missing-episode", "robot.bench", "replay {in}/nope.json", "nope.json"),
    ("replay-not-an-episode", "robot.bench", "replay {in}/plain.json", "not an episode file"),
    ("belief-missing-episode", "robot.bench", "belief {in}/nope.json", "nope.json"),
    ("belief-unknown-field", "robot.bench", "belief {in}/plain.json --set colour=1", "no field 'colour'"),
    ("belief-json-is-a-folder", "robot.bench", "belief {in}/plain.json --json {in}/folder", "--json"),
    ("bearing-not-a-map", "robot.bench", "bearing {in}/folder", "manifest.json"),
    ("bearing-unknown-node", "robot.bench", "bearing {map} --world {world} --nodes 9999", "9999"),
    ("bearing-bad-appearances", "robot.bench", "bearing {map} --appearances a,b", "--appearances"),
    ("bearing-json-is-a-folder", "robot.bench", "bearing {map} --json {in}/folder", "--json"),
    ("compare-missing-run", "robot.bench", "compare {in}/norun", "no such run folder"),
    ("compare-not-a-run", "robot.bench", "compare {in}/folder", "no episodes/ folder"),
    ("sim-steps-zero", "robot.bench", "sim --world {world} --steps 0", "--steps"),
    ("baseline-map-missing", "robot.bench", "baseline --map {in}/nomap --out {out}", "--map"),
    # the Limo tools
    ("monitor-negative-seconds", "limo.monitor", "--seconds -1", "--seconds"),
    ("monitor-port-missing", "limo.monitor", "--port /dev/ttyNOPE --seconds 0.2", "/dev/ttyNOPE"),
    ("monitor-config-is-a-folder", "limo.monitor", "--config {in}/folder", "is a folder"),
    ("monitor-config-bad-sign", "limo.monitor", "--config {in}/gyro.yaml", "serial.gyro_yaw_sign"),
    ("emulator-unknown-fault", "limo.emulator", "--fault melt", "unknown fault 'melt'"),
    ("emulator-negative-duration", "limo.emulator", "--duration -1", "--duration"),
    # the world checker
    ("topdown-unknown-world", "sim.topdown", "nowhere", "no world named 'nowhere'"),
    ("topdown-bad-field", "sim.topdown", "{in}/bad_world.yaml", "floor.size_m"),
]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("inputs")
    (root / "folder").mkdir()
    (root / "folder" / "a.txt").write_text("not an image")
    (root / "file.txt").write_text("plain text")
    (root / "garbage.mp4").write_bytes(b"not a video at all")
    (root / "garbage.yaml").write_text("mapping: [unclosed\n")
    (root / "sparsity.yaml").write_text("mapping:\n  sparsity: 2\n")
    (root / "typo.yaml").write_text("navigation:\n  heading_hint: true\n")
    (root / "gyro.yaml").write_text("serial:\n  gyro_yaw_sign: 3\n")
    (root / "plain.json").write_text('{"hello": 1}\n')
    recording = root / "broken_recording"
    recording.mkdir()
    (recording / "summary.json").write_text("{ this is not json")
    (root / "bad_world.yaml").write_text(TINY_WORLD.read_text().replace("size_m: [6.0, 4.0]", "size_m: [6.0, wide]"))
    return root


def _run(case, inputs: Path, tiny_map: Path, work: Path) -> tuple[subprocess.CompletedProcess, Path]:
    _, module, args, _ = case
    out = work.parent / f"{work.name}-out"
    argv = args.format(**{"in": inputs, "map": tiny_map, "world": TINY_WORLD, "out": out}).split()
    return subprocess.run([sys.executable, "-m", module, *argv], capture_output=True, text=True, cwd=work,
                          timeout=180), out


@pytest.fixture(scope="module")
def results(inputs, tiny_mapping_run, tmp_path_factory):
    """Every case run once (two at a time: the machine has two cores)."""
    root = tmp_path_factory.mktemp("work")
    works = {case[0]: root / case[0] for case in CASES}
    for work in works.values():
        work.mkdir()
    project = Path(__file__).resolve().parents[1]
    # the subprocesses import the project from its folder, whatever their working folder
    import os
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(project), os.environ.get("PYTHONPATH")]))
    with ThreadPoolExecutor(2) as pool:
        done = dict(zip(works, pool.map(lambda c: _run(c, inputs, tiny_mapping_run / "map", works[c[0]]), CASES)))
    return {name: (proc, out, works[name]) for name, (proc, out) in done.items()}


def test_there_are_at_least_forty_cases_over_every_command():
    assert len(CASES) >= 40 and len({c[0] for c in CASES}) == len(CASES)
    assert {c[1] for c in CASES} == {"robot.run", "robot.bench", "limo.monitor", "limo.emulator", "sim.topdown"}


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_bad_input_gets_one_line_and_exit_2(case, results):
    name, _, _, must = case
    proc, out, work = results[name]
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    assert must in lines[0], lines[0]
    assert not out.exists(), f"{out} was written"
    assert not any(work.iterdir()), f"wrote {[p.name for p in work.iterdir()]} into the working folder"
