"""Fixtures: a live executor of the simulated mini-Hubo right leg, in a domain of its own.

The executor binary is ``$CONDUCTOR_EXECUTOR`` (the Rust test that runs this suite sets it),
else ``target/debug/conductor-executor`` of the workspace; the suite fails, never skips, when
there is none (build it with ``cargo build -p conductor-executor``).
"""

import itertools
import os
import pathlib
import signal
import subprocess
import tempfile
import threading

import pytest

WORKSPACE = pathlib.Path(__file__).resolve().parents[2]
MANIFEST = WORKSPACE / "deploy" / "minihubo-right-leg.toml"
SUBSYSTEM = "right_leg"
_count = itertools.count()


def executor_binary() -> pathlib.Path:
    exe = pathlib.Path(
        os.environ.get("CONDUCTOR_EXECUTOR") or WORKSPACE / "target/debug/conductor-executor"
    )
    if not exe.exists():
        pytest.fail(
            f"{exe} not found: build it (cargo build -p conductor-executor) or set "
            "CONDUCTOR_EXECUTOR",
            pytrace=False,
        )
    return exe


class Executor:
    """A ``conductor-executor`` process running the leg in a fresh domain."""

    def __init__(self, manifest: pathlib.Path = MANIFEST, subsystem: str = SUBSYSTEM):
        self.domain = f"pytest-{os.getpid()}-{next(_count)}"
        self.log = tempfile.TemporaryFile(mode="w+")
        self.proc = subprocess.Popen(
            [
                str(executor_binary()),
                "--manifest",
                str(manifest),
                "--subsystem",
                subsystem,
                "--domain",
                self.domain,
                "--no-rt",
            ],
            stdout=subprocess.PIPE,
            stderr=self.log,
            text=True,
        )
        ready = threading.Event()

        def read():
            for line in self.proc.stdout:
                if line.strip() == "READY":
                    ready.set()

        threading.Thread(target=read, daemon=True).start()
        if not ready.wait(60):
            self.stop()
            pytest.fail(f"executor not READY within 60 s:\n{self.stderr()}", pytrace=False)

    def stderr(self) -> str:
        self.log.seek(0)
        return self.log.read()

    def stop(self) -> int:
        """SIGTERM, and the exit status (0: an orderly stop)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


@pytest.fixture(scope="module")
def leg():
    """One executor shared by a test module."""
    ex = Executor()
    yield ex
    code = ex.stop()
    assert code == 0, f"executor exited {code}:\n{ex.stderr()}"


@pytest.fixture
def own_leg():
    """An executor of the test's own (for tests that trip the watchdog or stop it)."""
    ex = Executor()
    yield ex
    ex.stop()


def manifest_states():
    """The leg's states as the manifest declares them, in bus-index order."""
    import tomllib

    with open(MANIFEST, "rb") as f:
        m = tomllib.load(f)
    return m["subsystems"][SUBSYSTEM]

