"""Helpers shared by the tests: importing a script, running the play server, reading a run directory's CSV files."""

from __future__ import annotations

import csv
import importlib.util
import re
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
import torch

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load_script(name: str):
    """Import ``scripts/<name>.py`` as a module (the scripts directory is not a package); it is registered in
    ``sys.modules`` because dataclasses look their module up there."""
    spec = importlib.util.spec_from_file_location(f"evaaa_scripts_{name}", SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@contextmanager
def play_server(workdir: Path, *args: str, participant: str = "tester", start_timeout: float = 120) -> Iterator[str]:
    """Run ``scripts/play.py level=1-1 participant=<participant> port=0 *args`` in ``workdir``; yield its base URL
    (``http://127.0.0.1:<port>/``).  On leaving, the server is sent SIGTERM and must exit cleanly (status 0)."""
    log_path = workdir / "play.log"
    with log_path.open("w") as log:
        proc = subprocess.Popen(
            [sys.executable, str(SCRIPTS / "play.py"), "level=1-1", f"participant={participant}", "port=0", *args],
            cwd=workdir,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    try:
        deadline = time.monotonic() + start_timeout
        while not (found := re.search(r"open (http://\S+/) ", log_path.read_text())):
            if proc.poll() is not None:
                pytest.fail(f"play.py exited with status {proc.returncode}:\n{log_path.read_text()}")
            if time.monotonic() > deadline:
                pytest.fail(f"play.py did not start in {start_timeout} s:\n{log_path.read_text()}")
            time.sleep(0.1)
        yield found.group(1)
    finally:
        proc.terminate()
        try:
            code = proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            pytest.fail(f"play.py did not stop on SIGTERM:\n{log_path.read_text()}")
    assert code == 0, f"play.py exited with status {code} on SIGTERM:\n{log_path.read_text()}"


def decode_mp4(path: Path) -> list:
    """Every frame of an mp4 file as RGB uint8 arrays, decoded with OpenCV."""
    import cv2

    video = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = video.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB))
    video.release()
    return frames


def video_stream(path: Path) -> str:
    """How ffmpeg (the one imageio-ffmpeg ships) describes the video stream of ``path``: codec first, then pixel
    format and size, e.g. ``h264 (High) (avc1 / 0x31637661), yuv420p(progressive), 64x64, ...``."""
    import imageio_ffmpeg

    probe = subprocess.run(
        [imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)], capture_output=True, text=True
    )
    streams = [line.split("Video:", 1)[1].strip() for line in probe.stderr.splitlines() if "Video:" in line]
    assert streams, f"ffmpeg finds no video stream in {path}:\n{probe.stderr}"
    return streams[0]


#: the columns two identical runs differ in: when a row was written and the CPU time spent until then
CLOCK_COLUMNS = ("wall_time", "cpu_seconds")


def read_csv(path: Path) -> list[dict]:
    """A run's CSV rows without their clock columns (:data:`CLOCK_COLUMNS`)."""
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k not in CLOCK_COLUMNS} for row in csv.DictReader(f)]


def train_scalars(run_dir: Path) -> dict[str, dict[int, str]]:
    """The logger's training metrics, the last value written per step (a resumed run re-logs the lost steps)."""
    out = {}
    for path in sorted((run_dir / "logs" / "scalars" / "train").glob("*.csv")):
        with open(path) as f:
            out[path.stem] = {int(step): value for step, value in csv.reader(f)}
    return out


#: the device a killed test run resumes on.  Where ``device=auto`` is the CPU, ``cpu``: a changed ``device`` setting
#: then resumes too, to the same weights.  On a CUDA machine ``auto``: the GPU's sums differ from the CPU's in the
#: last bits, so only a resume on the same device can equal the uninterrupted run (the crossing from CUDA to the
#: CPU has its own test there).
RESUME_DEVICE = "auto" if torch.cuda.is_available() else "cpu"


@contextmanager
def ray_head(temp: Path, cpus: int = 2, start_timeout: float = 300) -> Iterator[str]:
    """A Ray head on 127.0.0.1 with ``cpus`` worker CPUs and no GPU, its files under ``temp``: yields its address.

    ``ray start --block`` in a session of its own, ended by signalling that session (``ray stop`` would stop every
    Ray instance of the machine's user, not only this one)."""
    import os
    import signal
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    log_path = temp / "ray-start.log"
    cmd = [
        str(Path(sys.executable).parent / "ray"),
        "start",
        "--head",
        "--block",
        "--node-ip-address=127.0.0.1",
        f"--port={port}",
        f"--num-cpus={cpus}",
        "--num-gpus=0",
        "--include-dashboard=false",
        f"--temp-dir={temp}",
        "--disable-usage-stats",
    ]
    # no token authentication (Ray turns it on where ~/.ray/auth_token exists, and the tests' clients send none)
    env = {**os.environ, "RAY_AUTH_MODE": "disabled"}
    with open(log_path, "w") as log:
        head = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, env=env)
    try:
        deadline = time.monotonic() + start_timeout
        while "Ray runtime started" not in log_path.read_text():
            if head.poll() is not None or time.monotonic() > deadline:
                pytest.fail(f"ray start did not start a head: {log_path.read_text()[-2000:]}")
            time.sleep(0.5)
        yield f"127.0.0.1:{port}"
    finally:
        # SIGTERM: ray start stops the processes it started; SIGKILL: whatever of its session is left. A graceful stop
        # took 35 s (its raylet waits for its workers), idle time of a test worker: this throwaway cluster gets 5 s
        for sig, wait in ((signal.SIGTERM, 5), (signal.SIGKILL, 30)):
            try:
                os.killpg(head.pid, sig)
            except ProcessLookupError:
                break
            try:
                head.wait(timeout=wait)
            except subprocess.TimeoutExpired:
                pass
