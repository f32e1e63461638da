"""common.interrupt: user code's own sys.exit() / KeyboardInterrupt is an ordinary failure
(UserCodeExit), a real SIGINT still interrupts, and the SIGINT handler is restored after use."""
from __future__ import annotations

import os
import signal
import sys
import time

import pytest

from calnav.common.interrupt import UserCodeExit, sigint_flag, sigint_received, user_code

SIGNAL_WAIT_S = 5.0   # a signal sent to this process is handled at the next bytecode; bound the wait


def test_sys_exit_in_user_code_is_a_failure():
    with pytest.raises(UserCodeExit, match=r"^plugin X called sys.exit\(\); a plugin reports a failure"):
        with user_code("plugin X"):
            sys.exit()
    with pytest.raises(UserCodeExit, match=r"^plugin X called sys.exit\(3\)"):
        with user_code("plugin X"):
            sys.exit(3)


def test_a_keyboard_interrupt_raised_by_user_code_is_a_failure():
    with sigint_flag(), pytest.raises(UserCodeExit, match=r"^plugin X raised KeyboardInterrupt itself"):
        with user_code("plugin X"):
            raise KeyboardInterrupt


def test_a_real_sigint_still_interrupts_user_code():
    with pytest.raises(KeyboardInterrupt):
        with sigint_flag(), user_code("plugin X"):
            os.kill(os.getpid(), signal.SIGINT)
            deadline = time.monotonic() + SIGNAL_WAIT_S
            while time.monotonic() < deadline:
                time.sleep(0.01)
    assert sigint_received()
    with sigint_flag():   # a new outermost use starts without the old record
        assert not sigint_received()


def test_sigint_flag_restores_the_handler():
    before = signal.getsignal(signal.SIGINT)
    with sigint_flag():
        with sigint_flag():
            assert signal.getsignal(signal.SIGINT) is not before
        assert signal.getsignal(signal.SIGINT) is not before   # the inner exit keeps the outer's handler
    assert signal.getsignal(signal.SIGINT) is before
