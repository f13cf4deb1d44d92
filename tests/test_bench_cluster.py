"""The harness's Ray runner (robot.bench.cluster): what travels to the workers, and the arguments
and failures answered before any work. The episodes themselves on a local Ray instance are in
tests/test_bench_paper.py (slow lane)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from robot.bench import cluster
from robot.bench.trials import Trial

ROOT = Path(__file__).resolve().parents[1]
TINY = str(ROOT / "tests" / "data" / "tiny_world.yaml")


def _folder(root: Path) -> Path:
    (root / "sub").mkdir(parents=True)
    (root / "manifest.json").write_text('{"nodes": 3}')
    (root / "sub" / "descriptors.npy").write_bytes(bytes(range(256)) * 40)
    return root


def _tree(root: Path) -> dict:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_a_packed_folder_and_file_unpack_to_the_same_content_once(tmp_path):
    source = _folder(tmp_path / "maps" / "hospital-s0.5")
    kind, data = cluster.pack(source)
    key = cluster.content_key(kind, source.name, data)
    node = tmp_path / "node-cache"
    here = cluster.materialise(kind, key, data, root=node)
    assert kind == "folder" and here.name == "hospital-s0.5" and _tree(here) == _tree(source)
    # a second worker of the node finds it and does not unpack again
    marker = here / "manifest.json"
    stamp = marker.stat().st_mtime_ns
    assert cluster.materialise(kind, key, data, root=node) == here and marker.stat().st_mtime_ns == stamp
    assert not [p for p in here.parent.iterdir() if p.name.startswith(".")]          # no debris left
    # other content, other key: a map rebuilt between two runs is not taken from the cache
    (source / "manifest.json").write_text('{"nodes": 4}')
    kind2, data2 = cluster.pack(source)
    assert cluster.content_key(kind2, source.name, data2) != key
    # a single file (the baseline's head, a world file, a --config file)
    head = tmp_path / "sptm_head.pt"
    head.write_bytes(b"\x80weights")
    kind, data = cluster.pack(head)
    path = cluster.materialise(kind, cluster.content_key(kind, head.name, data), data, root=node)
    assert kind == "file" and path.name == "sptm_head.pt" and path.read_bytes() == b"\x80weights"


def test_a_worker_that_loses_the_race_uses_the_winners_copy(tmp_path, monkeypatch):
    source = _folder(tmp_path / "m")
    kind, data = cluster.pack(source)
    key = cluster.content_key(kind, "m", data)
    node = tmp_path / "cache"
    first = {}
    real_commit = cluster.AtomicFolder.commit_unless_present

    def another_worker_first(folder):          # another worker unpacked and published its copy first
        if not first:
            shutil.copytree(source, folder.target)
            (folder.target / "theirs").write_text("in use")
            first["inode"] = folder.target.stat().st_ino
        return real_commit(folder)
    monkeypatch.setattr(cluster.AtomicFolder, "commit_unless_present", another_worker_first)
    here = cluster.materialise(kind, key, data, root=node)
    assert here.stat().st_ino == first["inode"] and (here / "theirs").exists()   # theirs is kept
    assert [p.name for p in here.parent.iterdir()] == ["m"]                        # ours is gone


def test_an_episode_ships_what_it_reads_and_nothing_of_the_package(tmp_path):
    base = dict(route="short", method="sptm", trial=0, appearance_seed=1, start_x_m=0.0, start_y_m=0.0,
                start_yaw_deg=0.0, offset_m=0.0, offset_yaw_deg=0.0, shortest_length_m=1.0)
    head = tmp_path / "head.pt"
    head.write_bytes(b"x")
    by_file = Trial(world=TINY, map_dir=str(tmp_path / "map"), baseline_path=str(head), **base)
    assert cluster._input_paths(by_file) == [str(tmp_path / "map"), str(head), TINY]
    by_name = Trial(world="hospital", map_dir="runs/paper/maps/hospital-s0.5", **{**base, "method": "ours"})
    assert cluster._input_paths(by_name) == ["runs/paper/maps/hospital-s0.5"]       # worlds by name are packaged
    absolute = cluster._absolute(by_name)
    assert Path(absolute.map_dir).is_absolute() and absolute.world == "hospital"


def _bench(*argv: str, block_ray: bool = False, timeout: float = 120) -> subprocess.CompletedProcess:
    code = ("import sys\n" + ("sys.modules['ray'] = None\n" if block_ray else "")
            + "from robot.bench.__main__ import main\nsys.exit(main(sys.argv[1:]))\n")
    return subprocess.run([sys.executable, "-c", code, "paper", *argv], capture_output=True, text=True,
                          cwd=ROOT, timeout=timeout)


@pytest.mark.parametrize("argv, block_ray, message", [
    (["--ray"], True, "pip install -e '.[cluster]'"),
    (["--ray-shared"], False, "--ray-shared needs --ray"),
    (["--ray", "auto", "--workers", "2"], False, "--workers with --ray auto"),
    (["--ray", "a-head-without-port"], False, "expected auto, HOST:PORT or ray://HOST:PORT"),
    (["--ray", "127.0.0.1:9"], False, "--ray 127.0.0.1:9: no Ray cluster answers there"),
])
def test_ray_arguments_and_an_unreachable_cluster_exit_2_before_any_work(argv, block_ray, message, tmp_path):
    out = tmp_path / "run"
    done = _bench("--routes", f"{TINY}:short", "--methods", "ours", "--trials", "1", "--sparsity", "none",
                  "--quiet", "--out", str(out), *argv, block_ray=block_ray)
    assert done.returncode == 2, done.stderr
    assert message in done.stderr and "Traceback" not in done.stderr
    assert not out.exists()                 # nothing mapped, nothing written (a hang hits _bench's timeout)
