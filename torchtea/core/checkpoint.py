"""Each part of a long run kept as it finishes, so that a stop — Ctrl-C, SIGTERM from a time limit or a batch
scheduler, a crash, a machine that goes away — loses only the part that was running, and the same command run again
goes on from there.

A :class:`Checkpoint` is a folder (``check``'s and ``export``'s ``OUT/partial``, ``fit``'s ``OUT.partial``) holding
``run.json`` — what makes two runs the same (:attr:`Checkpoint.identity`: the command, its flags that change results,
each input file's size and modification time) — and one pickle per finished part (a channel's check or fit), each
written to a temporary name and renamed, so that a part is whole or absent. A run with the same identity takes the
parts kept and says so; a run of another identity replaces them (``resume=None``) or is refused (``resume=True``,
``--resume``, which promises a run to go on) — when it keeps its own first part, so that a run stopped before that
loses nothing. The folder is removed when the run's outputs are written.

The pickles are this library's objects: read them only with the torchtea that wrote them (the identity holds its
version) and only from folders you made.
"""
from __future__ import annotations

import json
import os
import pickle
import shutil
from pathlib import Path

__all__ = ["Checkpoint", "CheckpointError", "file_identity"]

#: The name of the file that says whose parts a checkpoint folder holds.
RUN_FILE = "run.json"


class CheckpointError(ValueError):
    """``--resume`` without a run to go on (no folder, or one of another command, flags or input)."""


def file_identity(path) -> dict:
    """A file (or a folder: its files) by absolute path, size and modification time: what tells a changed input;
    a path that is not there, by its name."""
    p = Path(path).resolve()
    if not p.exists():
        return {"path": str(p), "missing": True}
    if p.is_dir():
        files = sorted(f for f in p.rglob("*") if f.is_file())
        return {"path": str(p), "files": [file_identity(f) for f in files]}
    st = p.stat()
    return {"path": str(p), "bytes": st.st_size, "mtime_ns": st.st_mtime_ns}


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("torchtea")
    except PackageNotFoundError:
        return "unknown"


class Checkpoint:
    """The parts of one run kept in ``folder``. ``identity``: a JSON-able dict of what makes the run the one it is
    (the torchtea version is added). ``resume``: True — the folder must hold parts of this very run (else
    :class:`CheckpointError`); None — take them if it does, else start afresh; False — start afresh. ``say(line)``
    takes the notes (what is taken, what is replaced)."""

    def __init__(self, folder, identity: dict, *, resume: bool | None = None, say=None):
        self.folder = Path(folder)
        # (as run.json holds it: tuples as lists, any other object as its text — so that a run compares equal to
        # the run it kept)
        self.identity = json.loads(json.dumps({**identity, "torchtea": _version()}, default=str))
        self.say = say or (lambda line: None)
        self.done: dict = {}
        self._fresh = True  # run.json (re)written and anything of another run cleared at the first keep
        found = self._found()
        if resume and found is None:
            raise CheckpointError(f"--resume: no interrupted run to go on in {self.folder} (it holds no readable "
                                  f"{RUN_FILE})")
        if resume and found != self.identity:
            differ = sorted(k for k in set(found) | set(self.identity) if found.get(k) != self.identity.get(k))
            raise CheckpointError(f"--resume: the run kept in {self.folder} is not this one (it differs in "
                                  f"{', '.join(differ)}); run without --resume to start afresh")
        if found is not None and found == self.identity and resume is not False:
            self.done = self._load()
            self._fresh = False
        elif self.folder.exists():
            self.say(f"the parts kept in {self.folder} are not of this run (another command, flags or input, or no "
                     f"readable {RUN_FILE}): this run starts afresh and replaces them when it keeps its first part")

    def _found(self) -> dict | None:
        try:
            return json.loads((self.folder / RUN_FILE).read_text())["identity"]
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def _load(self) -> dict:
        out = {}
        for f in sorted(self.folder.glob("*.pickle")):
            try:
                with open(f, "rb") as fh:
                    label, result = pickle.load(fh)
            except Exception:  # a part written by a run that died mid-write is whole or absent; anything else, redone
                self.say(f"{f}: cannot be read, that part is run again")
                continue
            out[label] = result
        return out

    def keep(self, label: str, result) -> None:
        """Write one finished part (whole or not at all: a temporary file renamed)."""
        if self._fresh:  # (another run's parts go only now: a run stopped before its first part loses nothing kept)
            shutil.rmtree(self.folder, ignore_errors=True)
            self.folder.mkdir(parents=True, exist_ok=True)
            text = json.dumps({"identity": self.identity, "meaning": "the parts of an interrupted torchtea run, kept "
                               "as each finished; the same command run again goes on from them"}, indent=1)
            self._write(RUN_FILE, text.encode())
            self._fresh = False
        name = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in label)
        self._write(f"{name}.pickle", pickle.dumps((label, result), protocol=pickle.HIGHEST_PROTOCOL))
        self.done[label] = result

    def _write(self, name: str, data: bytes) -> None:
        """A file whole or not at all: written to a temporary name, synced, renamed."""
        tmp = self.folder / f".{name}.tmp"
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self.folder / name)

    def finish(self) -> None:
        """The run's outputs are written: the parts are not needed any more."""
        shutil.rmtree(self.folder, ignore_errors=True)
