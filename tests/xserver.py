"""A virtual X server of the tests' own, for the GUI doors.

``xvfb-run`` is not used: its exit status is its own when it fails to clean up its temporary directory (status 5,
"problem while cleaning up temporary directory", seen once in CI under ParaView's GUI), and the tests assert the
door's own exit status. Here Xvfb picks a free display and reports it on a pipe (``-displayfd``); the door runs with
``DISPLAY`` set, and its exit status is the one the test sees.
"""
import contextlib
import os
import select
import shutil
import subprocess
import time

import pytest

XVFB_SCREEN = "1280x1024x24"  # xvfb-run's default screen, which the pictures' thresholds were set against


@contextlib.contextmanager
def virtual_display(screen=XVFB_SCREEN, seconds=60):
    """Yield ``":N"``, the display of a fresh Xvfb with one screen of ``screen``; skip when Xvfb is not installed."""
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.skip("Xvfb is not installed (apt-get install xvfb)")
    read_end, write_end = os.pipe()
    proc = subprocess.Popen([xvfb, "-displayfd", str(write_end), "-screen", "0", screen, "-nolisten", "tcp"],
                            pass_fds=(write_end,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(write_end)
    number, deadline = b"", time.monotonic() + seconds
    try:
        while not number.endswith(b"\n") and time.monotonic() < deadline:
            if not select.select([read_end], [], [], max(deadline - time.monotonic(), 0))[0]:
                break
            chunk = os.read(read_end, 32)
            if not chunk:
                break
            number += chunk
    finally:
        os.close(read_end)
    if not number.strip():
        proc.kill()
        proc.wait()
        pytest.fail(f"Xvfb did not report a display within {seconds} s")
    try:
        yield ":" + number.decode().strip()
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
