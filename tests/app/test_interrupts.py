"""Ctrl-C and SIGTERM at any moment of `coplanar run` and `coplanar sweep`: one line, and
either every output file or none; a sweep keeps its finished runs whole, leaves no Ray
process behind and resumes (scripts/interrupt_check.py, here with fewer signals than its
50)."""

from __future__ import annotations

import pathlib
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "scripts"))

from interrupt_check import RUN, check, start, trial  # noqa: E402


def test_signals_at_random_moments_leave_all_outputs_or_none() -> None:
    assert check("room", times=6, seed=1) == []


@pytest.mark.parametrize("name", ["sweep-serial", "sweep-ray"])
def test_signals_at_random_moments_of_a_sweep_leave_whole_runs_and_it_resumes(name: str) -> None:
    if name == "sweep-ray":
        pytest.importorskip("ray", reason="Ray is not installed")
    assert check(name, times=3, seed=2) == []


def test_a_signal_while_the_command_line_loads_is_one_line(tmp_path: pathlib.Path) -> None:
    """The first fraction of a second: the modules loading (it printed a 7-41-line
    traceback). A signal in Python's own start-up, before the project's code runs, is
    tried again a little later."""
    for number, at_s in enumerate((0.05, 0.15, 0.3)):
        t = trial([*RUN, "--scene", "room", "--duration", "1"], tmp_path, at_s=at_s, number=number)
        while t.in_interpreter_startup:
            at_s += 0.05
            t = trial([*RUN, "--scene", "room", "--duration", "1"], tmp_path, at_s=at_s, number=number)
        assert t.problem == "" and t.returncode == 130, (at_s, t)
        assert t.stderr.strip().splitlines() in (["interrupted"], [f"interrupted: nothing written to {tmp_path / f'out{number}'}"]), t.stderr


def test_start_runs_the_command_as_a_user_would(tmp_path: pathlib.Path) -> None:
    process = start([*RUN, "--scene", "mc-a", "--keyframes", "2"], tmp_path / "out")
    assert process.wait(timeout=300) == 0


def test_an_interrupt_wrapped_by_compiled_code_is_an_interruption(monkeypatch, capsys) -> None:
    """numba's dispatcher turned a Ctrl-C into "SystemError: ... returned a result with an
    exception set" (a traceback, exit 1)."""
    from app import cli, run_command

    def interrupted(args):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher(<function landmark_rows>) returned a result with an exception set") from None

    monkeypatch.setattr(run_command, "run", interrupted)
    assert cli.main(["run", "--scene", "mc-a", "--variant", "P-wo", "--out", "unused"]) == 130
    assert capsys.readouterr().err == "interrupted\n"


def test_an_interrupt_turned_into_another_error_by_c_code_is_an_interruption(monkeypatch, capsys) -> None:
    """A Ctrl-C while NumPy's C extensions import `datetime` became "ImportError: ...
    PyCapsule_Import could not import module "datetime"", with nothing of the interrupt left
    in its chain (a traceback, exit 1; CI, 2026-11-28). A real SIGINT here, and an error
    raised after it with no link to it."""
    import os
    import signal
    import time

    from app import cli, run_command

    def interrupted(args):
        swallowed = False
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)  # the handler raises KeyboardInterrupt here
        except KeyboardInterrupt:
            swallowed = True
        if swallowed:  # raised outside the except block: no __context__, as from C code
            raise ImportError('PyCapsule_Import could not import module "datetime"')

    monkeypatch.setattr(run_command, "run", interrupted)
    assert cli.main(["run", "--scene", "mc-a", "--variant", "P-wo", "--out", "unused"]) == 130
    assert capsys.readouterr().err == "interrupted\n"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # main() put Python's handler back


def test_an_interrupt_swallowed_in_a_finalizer_on_the_main_thread_is_an_interruption(monkeypatch, capsys) -> None:
    """A SIGTERM that landed in an object's finalizer on the main thread ("Exception ignored
    in ...") was raised again inside the hook itself, swallowed a second time: a traceback
    and exit 0 from a serial sweep (scripts/interrupt_check.py --inputs sweep-serial)."""
    import gc
    import time

    from app import cli, run_command

    class Finalized:
        def __del__(self) -> None:
            raise KeyboardInterrupt

    def finalizes_then_works(args):
        Finalized()
        gc.collect()
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:  # the run goes on, as the sweep's did
            time.sleep(0.01)
        return 0

    monkeypatch.setattr(run_command, "run", finalizes_then_works)
    assert cli.main(["run", "--scene", "mc-a", "--variant", "P-wo", "--out", "unused"]) == 130
    captured = capsys.readouterr()
    assert captured.err == "interrupted\n", captured.err
