"""Helpers for tests that run torchtea in a child process."""
import signal


def sigint_as_in_a_terminal():
    """``preexec_fn`` for a child that a test stops with SIGINT, as Ctrl-C in a terminal would.

    A shell without job control starts background commands (``cmd &``, and everything they start) with SIGINT
    ignored, and Python keeps an ignored SIGINT ignored. Under such a parent a SIGINT would never reach the
    child as KeyboardInterrupt; the default disposition lets Python install its handler.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)
