"""Helpers for tests that run torchtea in a child process."""
import os
import signal
import time


def sigint_as_in_a_terminal():
    """``preexec_fn`` for a child that a test stops with SIGINT, as Ctrl-C in a terminal would.

    A shell without job control starts background commands (``cmd &``, and everything they start) with SIGINT
    ignored, and Python keeps an ignored SIGINT ignored. Under such a parent a SIGINT would never reach the
    child as KeyboardInterrupt; the default disposition lets Python install its handler.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def wait_for_progress(path, proc, at_least: int, timeout: float, poll: float = 0.05) -> int:
    """Wait until the first number in ``path`` (a ``--progress-file``) reaches ``at_least``, the process ends or
    ``timeout`` seconds pass; returns the last number read (0 if none)."""
    deadline = time.monotonic() + timeout
    done = 0
    while done < at_least and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(poll)
        try:
            done = int(path.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            pass
    return done


def kill_a_busy_worker(client, pids: dict, killed: list):
    """A ``progress(done, total)`` callback for a run on ``client``'s cluster: the first time a worker is processing a
    task, SIGKILL its process (``pids``: worker address → pid, ``client.run(os.getpid)``) and append ``(address, the
    keys it was processing)`` to ``killed``; nothing after that."""

    def kill(done, total):
        if killed:
            return
        busy = [addr for addr, keys in client.processing().items() if keys]
        if busy:
            killed.append((busy[0], client.processing()[busy[0]]))
            os.kill(pids[busy[0]], signal.SIGKILL)

    return kill
