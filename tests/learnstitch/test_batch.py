"""Many clips of one rig, chunk by chunk (learnstitch.video.batch), on this machine and on a Ray
cluster of two nodes this module starts itself (Ray's own multi-node test cluster, every process
on 127.0.0.1, no usage statistics).

The cluster's videos against the single-machine run of the same chunking (threads pinned), frame
by frame after decoding; a worker node removed mid-run, then the same comparison; a run killed
with SIGKILL, then rerun: only the missing chunks stitched and the same frames; each bad input's
one line.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import mp4_boxes  # tests/learnstitch/mp4_boxes.py, the independent reader
import numpy as np
import pytest
from test_video import RATE, SIZE, SPF, audio_packets, decode_rgb, noise, write_clip

from learnstitch.cli import main
from learnstitch.data.dual import draw_dual, render_dual_frames
from learnstitch.fullres.config import RenderConfig
from learnstitch.video import Encoding
from learnstitch.video.batch import read_clip_list, stitch_batch
from learnstitch.video.chunks import Clip
from learnstitch.video.cluster import LOCAL_ENVIRONMENT

os.environ.update(LOCAL_ENVIRONMENT)  # before Ray is imported (it reads them then): 127.0.0.1 its own address
ray = pytest.importorskip("ray")

WIDTH, CHUNK = 128, 3
LENGTHS = (4, 7, 5, 8)  # the four clips' frames: chunk boundaries at 3 and 6, a short last chunk
TEMPLATE = {"mode": "template", "width": WIDTH}
LOSSLESS = Encoding(crf=0, preset="ultrafast")
SMALL = RenderConfig(working_width=64, depth_planes=8)  # a small working canvas for small frames


@pytest.fixture(scope="module")
def footage(tmp_path_factory):
    """A dual-fisheye camera's rig and four side-by-side clips of it, turning, with audio; the
    template maps cached in a folder of the module's own (the Ray workers inherit it)."""
    folder = tmp_path_factory.mktemp("batch")
    truth = draw_dual(5, SIZE)
    rig = folder / "rig.pto"
    truth.project(("left.png", "right.png"), panorama_width=WIDTH).save(rig)
    clips = []
    for k, count in enumerate(LENGTHS):
        frames = render_dual_frames(10 + k, truth, count, turn_deg=2.0)
        clips.append(write_clip(folder / f"clip{k}.mp4", frames, audio=noise(count * SPF, seed=k)))
    saved = os.environ.get("LEARNSTITCH_CACHE_DIR")
    os.environ["LEARNSTITCH_CACHE_DIR"] = str(folder / "cache")
    yield folder, rig, clips
    if saved is None:
        os.environ.pop("LEARNSTITCH_CACHE_DIR")
    else:
        os.environ["LEARNSTITCH_CACHE_DIR"] = saved


@pytest.fixture(scope="module")
def single(footage):
    """The four clips stitched on this machine, no Ray: the reference (and the template maps cached)."""
    folder, rig, clips = footage
    report = stitch_batch(
        rig, clips, folder / "single", chunk_frames=CHUNK, options=TEMPLATE, encoding=LOSSLESS, threads=1
    )
    assert not report.failed and report.where == "this machine"
    return {Path(c).stem: decode_rgb(folder / "single" / f"{Path(c).stem}.mp4") for c in clips}


def start_cluster():
    from ray.cluster_utils import Cluster

    cluster = Cluster(
        initialize_head=True,
        head_node_args={"num_cpus": 1, "node_ip_address": "127.0.0.1", "include_dashboard": False},
    )
    worker = cluster.add_node(num_cpus=1, node_ip_address="127.0.0.1")
    return cluster, worker


def assert_same_videos(out: Path, single: dict) -> None:
    for name, frames in single.items():
        got = decode_rgb(out / f"{name}.mp4")
        assert len(got) == len(frames)
        for a, b in zip(got, frames):
            np.testing.assert_array_equal(a, b)


def test_clips_stitched_on_a_two_node_cluster_are_the_single_machine_frames(footage, single):
    folder, rig, clips = footage
    assert [len(f) for f in single.values()] == list(LENGTHS)
    cluster, _ = start_cluster()
    try:
        report = stitch_batch(
            rig,
            clips,
            folder / "cluster",
            ray=cluster.address,
            chunk_frames=CHUNK,
            options=TEMPLATE,
            encoding=LOSSLESS,
            threads=1,
        )
    finally:
        cluster.shutdown()
    assert not report.failed and report.rerun == 0
    assert [r.chunks for r in report.clips] == [-(-n // CHUNK) for n in LENGTHS]
    assert len({r["pid"] for r in report.records}) == 2  # both nodes' actors stitched chunks
    assert_same_videos(folder / "cluster", single)
    assert not list((folder / "cluster").glob("*.parts"))  # the segments are gone once joined
    # As stitch --video writes it: the clip's audio packets over its frames copied, the spherical
    # metadata (read by the tests' own box reader)
    for clip, count in zip(clips, LENGTHS):
        out = folder / "cluster" / f"{Path(clip).stem}.mp4"
        assert audio_packets(out) == audio_packets(clip, 0.0, count / RATE) and audio_packets(out)
        [track] = mp4_boxes.spherical(out)
        assert track["v1"][0]["ProjectionType"] == "equirectangular" and track["stereo_mode"] == [0]


def test_a_killed_run_reruns_only_its_missing_chunks(footage, single):
    folder, rig, clips = footage
    out = folder / "killed"
    command = [sys.executable, "-m", "learnstitch.cli", "batch", "--rig", str(rig), *map(str, clips), "-o", str(out)]
    command += ["--mode", "template", "--width", str(WIDTH), "--chunk-frames", str(CHUNK), "--crf", "0"]
    command += ["--preset", "ultrafast", "--threads", "1", "--quiet"]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while len(list(out.glob("*.parts/chunk-*.json"))) < 3 and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    process.send_signal(signal.SIGKILL)
    process.wait()
    done = len(list(out.glob("*.parts/chunk-*.json"))) + 2 * len(list(out.glob("*.mp4")))  # clips joined: 2 chunks
    total = sum(-(-n // CHUNK) for n in LENGTHS)
    assert 3 <= done < total
    rerun = subprocess.run(command, capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    stitched = sum(
        int(line.split(", ")[1].split(" of ")[0]) for line in rerun.stdout.splitlines() if " chunks stitched" in line
    )
    assert stitched == total - done, rerun.stdout
    assert_same_videos(out, single)


def test_a_clip_that_cannot_be_opened_is_named_and_the_others_are_written(footage, tmp_path, capsys):
    folder, rig, clips = footage
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"not a video")
    args = ["batch", "--rig", str(rig), str(clips[0]), str(broken), "-o", str(tmp_path / "out")]
    status = main([*args, "--mode", "template", "--width", str(WIDTH), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2
    assert len(err) == 1 and str(broken) in err[0]
    assert (tmp_path / "out" / "clip0.mp4").exists() and not (tmp_path / "out" / "broken.mp4").exists()


def test_a_truncated_clip_is_stitched_to_its_last_decodable_frame(footage, tmp_path):
    folder, rig, clips = footage
    cut = write_clip(tmp_path / "cut.mp4", decode_rgb(clips[3]), faststart=True)  # the index first
    data = cut.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])  # the frames end where the file does
    report = stitch_batch(rig, [cut], tmp_path / "out", chunk_frames=CHUNK, options=TEMPLATE, encoding=LOSSLESS)
    (clip,) = report.clips
    assert clip.error is None and 0 < clip.frames < LENGTHS[3]
    assert (
        len(clip.warnings) == 1
        and str(cut) in clip.warnings[0]
        and f"ends at frame {clip.frames - 1}" in clip.warnings[0]
    )
    assert len(decode_rgb(tmp_path / "out" / "cut.mp4")) == clip.frames


def test_an_address_nobody_answers_at_is_one_line_and_starts_nothing(footage, tmp_path, capsys):
    folder, rig, clips = footage
    status = main(["batch", "--rig", str(rig), str(clips[0]), "-o", str(tmp_path / "out"), "--ray", "127.0.0.1:9"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "127.0.0.1:9" in err[0] and "no Ray cluster answers" in err[0]
    assert not (tmp_path / "out").exists() and not ray.is_initialized()


def test_a_clip_list_names_groups_offsets_and_outputs(tmp_path):
    listing = tmp_path / "clips.txt"
    listing.write_text("# two rigs' worth\na.mp4\ncam0.mp4 cam1.mp4 offsets=0,12 out=street.mp4  # per camera\n\n")
    clips = read_clip_list(listing, tmp_path / "out")
    assert clips == [
        Clip((str(tmp_path / "a.mp4"),), str(tmp_path / "out" / "a.mp4")),
        Clip((str(tmp_path / "cam0.mp4"), str(tmp_path / "cam1.mp4")), str(tmp_path / "out" / "street.mp4"), (0, 12)),
    ]
    listing.write_text("a.mp4\nb.mp4 offsets=zero\n")
    with pytest.raises(Exception, match=r"clips.txt, line 2: offsets=zero"):
        read_clip_list(listing, tmp_path / "out")


def test_a_worker_node_lost_mid_run_loses_no_chunk_and_the_depth_aware_frames_are_this_machines(footage):
    """Two clips in the depth-aware mode (the temporal filter on, restarted at each chunk's first
    frame and primed on the frames before it, more than a chunk's) on the cluster, its worker node
    removed once a first chunk is done: each actor's first chunk includes its set-up (seconds), so
    the other actor is then mid-chunk, or the first one mid-way through its next. The videos are
    those of this machine's run of the same chunking."""
    folder, rig, clips = footage
    depth = {"mode": "depth", "model": "sweep", "width": WIDTH, "config": SMALL}
    settings = dict(chunk_frames=CHUNK, options=depth, encoding=LOSSLESS, threads=1)
    chosen = [clips[1], clips[3]]
    single = stitch_batch(rig, chosen, folder / "depth_single", **settings)
    out = folder / "depth_lost"
    cluster, worker = start_cluster()
    removed = threading.Event()

    def remove_when_a_chunk_is_done():
        deadline = time.monotonic() + 300
        while not list(out.glob("*.parts/chunk-*.json")) and time.monotonic() < deadline:
            time.sleep(0.005)
        cluster.remove_node(worker)
        removed.set()

    remover = threading.Thread(target=remove_when_a_chunk_is_done)
    remover.start()
    try:
        report = stitch_batch(rig, chosen, out, ray=cluster.address, **settings)
    finally:
        remover.join()
        cluster.shutdown()
    assert removed.is_set() and not single.failed and not report.failed
    assert [c.chunks for c in report.clips] == [3, 3]
    assert report.rerun >= 1, report.summary()
    assert "run again after their worker was lost" in report.summary()
    assert_same_videos(out, {Path(c).stem: decode_rgb(folder / "depth_single" / f"{Path(c).stem}.mp4") for c in chosen})
