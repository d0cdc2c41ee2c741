"""Plugin code in a child process, so that a crash of its native code does not end the run.

A plugin loaded by its spec (``--plugin``, :func:`crosscheck.backends.load_plugin`) or from an entry point has its
``split`` and ``split_chart`` evaluated in one long-lived child process per plugin and per evaluating process (the
gate's own, or each worker of ``--workers``), fed by pipes: the child is ``python -c`` with this process's
``sys.path`` and working directory, and loads the plugin there by its spec (the checked function is sent pickled:
``crosscheck.backends._Checked.__reduce__``). Each model is sent once per child and then named by a token. A plugin
whose native code crashes (a segfault in a C extension, ``ctypes.string_at(0)``, ``os._exit``) kills its child only:
the call raises :class:`PluginCrashed` ("plugin 'X' crashed (signal SIGSEGV) in split on model 'arm'"), which the
gate reports as that backend's error at that state (``crosscheck.engine.evaluation``), and the next call starts a new
child. After :data:`CRASHES_IN_A_ROW` crashes in a row the plugin is not called again until :func:`new_case`: every
later call raises at once, with the same message, so that a plugin that cannot run costs no more than a few
crashes and the report counts one error, not one per state.

Not isolated, run in the evaluating process: a plugin registered as an object (:func:`crosscheck.backends.register`:
no spec to load it by in another process), a call whose arguments cannot be pickled, and every call when
:data:`ENV` is ``"0"`` (a debugger in the plugin, or a plugin that must share the process). In the child itself,
calls run in place (:func:`isolated` is False there).

Exceptions the plugin raises cross back as they are (``ModelNotSupported`` stays NOT COMPARED); the plugin's output on
stdout goes to stderr in the child (stdout carries the protocol). A child ignores Ctrl-C (the parent stops the run)
and ends when its parent closes the pipe.
"""

from __future__ import annotations

import atexit
import dataclasses
import itertools
import json
import os
import pickle
import signal
import struct
import subprocess
import sys
import threading
from typing import Any, Callable

#: The environment variable that keeps plugins in the evaluating process when set to "0".
ENV = "CROSSCHECK_ISOLATE"

#: Crashes in a row after which a plugin is no longer called until the next case (:func:`new_case`).
CRASHES_IN_A_ROW = 3

#: Models a child keeps by token; past this many the parent and the child both forget them and start again.
MODELS_KEPT = 64

_HEADER = struct.Struct("<Q")
_in_child = False


class _Unpicklable(Exception):
    """A call whose arguments cannot be pickled: it runs in the evaluating process."""


class PluginCrashed(RuntimeError):
    """A plugin's child process died during a call (a signal or an exit), or the plugin crashed too often in a row to
    be called again in this case."""


def isolated() -> bool:
    """Whether a plugin loaded by spec is evaluated in a child process here (not in a child, :data:`ENV` not "0")."""
    return not _in_child and os.environ.get(ENV, "1") != "0"


def _write(stream, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)) + data)
    stream.flush()


def _read(stream):
    """The next message, or EOFError when the other end has closed the pipe (or died)."""
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        raise EOFError
    data = stream.read(_HEADER.unpack(head)[0])
    if len(data) < _HEADER.unpack(head)[0]:
        raise EOFError
    return pickle.loads(data)


def _ended(code: int) -> str:
    """A child's exit status in words: the signal that killed it, or its exit code."""
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"exit code {code}"


class _Child:
    """One child process evaluating one plugin's calls (module docstring)."""

    def __init__(self):
        boot = ("import sys, json; sys.path[:] = json.loads(sys.argv[1]); "
                "import crosscheck.isolation as i; i.serve()")
        self.process = subprocess.Popen([sys.executable, "-c", boot, json.dumps(sys.path)], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, cwd=os.getcwd())
        self.models: dict[int, tuple[Any, int]] = {}   # id(model) -> (the model, kept alive; its token)
        self.functions: set[str] = set()
        self.tokens = itertools.count()

    def call(self, key: str, function: Callable[..., Any], model, args: tuple):
        """``function(model, *args)`` in the child: ``(True, its result)`` or ``(False, the exception it raised)``;
        EOFError when the child died; :class:`_Unpicklable` (nothing sent) when the call cannot be pickled."""
        forget = len(self.models) >= MODELS_KEPT and id(model) not in self.models
        known = {} if forget else self.models
        token = known[id(model)][1] if id(model) in known else next(self.tokens)
        message = (forget, key, None if key in self.functions else function, token,
                   None if id(model) in known else model, args)
        try:
            data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:  # a chart or an argument of the caller's that does not pickle
            raise _Unpicklable from exc
        if forget:
            self.models.clear()
        self.models.setdefault(id(model), (model, token))
        self.functions.add(key)
        try:
            self.process.stdin.write(_HEADER.pack(len(data)) + data)
            self.process.stdin.flush()
        except OSError:            # the child is gone (a broken pipe)
            raise EOFError from None
        ok, value, kept = _read(self.process.stdout)
        if not kept:               # the child could not unpickle this call: it holds neither its function nor its model
            self.functions.discard(key)
            self.models.pop(id(model), None)
        return ok, value

    def end(self) -> str:
        """Close the pipes and reap the child (dead, or ending on the closed pipe): its exit status in words."""
        for stream in (self.process.stdin, self.process.stdout):
            try:
                stream.close()
            except OSError:
                pass
        try:
            return _ended(self.process.wait(timeout=10))
        except subprocess.TimeoutExpired:
            self.process.kill()
            return _ended(self.process.wait())


@dataclasses.dataclass
class _Channel:
    """A plugin's child in this process, its crashes in a row and, past :data:`CRASHES_IN_A_ROW`, why it is no
    longer called."""

    child: _Child | None = None
    crashes: int = 0
    failed: str | None = None
    lock: threading.Lock = dataclasses.field(default_factory=threading.Lock)
    pid: int = dataclasses.field(default_factory=os.getpid)


_channels: dict[str, _Channel] = {}


def _channel(spec: str) -> _Channel:
    channel = _channels.get(spec)
    if channel is None or channel.pid != os.getpid():     # a forked copy does not share its parent's pipes
        channel = _channels[spec] = _Channel()
    return channel


def start(spec: str) -> None:
    """Start the child of the plugin loaded by ``spec`` now (when plugins are isolated here), so that its start-up
    (an interpreter importing the plugin) overlaps the work before the first call."""
    if isolated():
        channel = _channel(spec)
        with channel.lock:
            if channel.child is None:
                channel.child = _Child()


def call(spec: str, name: str, attribute: str, function: Callable[..., Any], model, args: tuple):
    """``function(model, *args)`` (the checked ``attribute``, ``split`` or ``split_chart``, of plugin ``name`` loaded by
    ``spec``) in the plugin's child process; in this process when the call cannot be pickled. Raises
    :class:`PluginCrashed` when the child dies during the call, or at once while the plugin is failed (module
    docstring)."""
    channel = _channel(spec)
    with channel.lock:
        if channel.failed is not None:
            raise PluginCrashed(channel.failed)
        if channel.child is None:
            channel.child = _Child()
        try:
            ok, out = channel.child.call(attribute, function, model, args)
        except _Unpicklable:
            return function(model, *args)
        except EOFError:
            how = channel.child.end()
            channel.child, channel.crashes = None, channel.crashes + 1
            if channel.crashes >= CRASHES_IN_A_ROW:
                channel.failed = (f"plugin '{name}' crashed {channel.crashes} times in a row (last: {how} in "
                                  f"{attribute} on model '{model.name}'): not called again in this case (run it "
                                  "alone, e.g. crosscheck eval, to see where)")
                raise PluginCrashed(channel.failed) from None
            raise PluginCrashed(f"plugin '{name}' crashed ({how}) in {attribute} on model '{model.name}'; its process "
                                "is started again for the next call") from None
        except BaseException:      # Ctrl-C while waiting: its answer would come to the next call, so the child goes
            channel.child.process.kill()
            channel.child.end()
            channel.child = None
            raise
        channel.crashes = 0
    if not ok:
        raise out
    return out


def stop_all() -> None:
    """End every child of this process (their pipes closed, each reaped): at exit, and when the plugins are
    forgotten (``crosscheck.backends.reset``)."""
    for spec, channel in list(_channels.items()):
        if channel.pid == os.getpid() and channel.child is not None:
            channel.child.end()
        del _channels[spec]


atexit.register(stop_all)


def new_case() -> None:
    """Forget the crashes counted so far: a plugin failed on one case is tried again on the next."""
    for channel in _channels.values():
        with channel.lock:
            channel.crashes, channel.failed = 0, None


def serve() -> None:
    """The child's loop (module docstring): read a call, answer ``(True, result, True)`` or ``(False, exception,
    kept)``, ``kept`` False when the call itself could not be unpickled (its function and model are not held)."""
    global _in_child
    _in_child = True
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    answers = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)                               # the plugin's prints go to stderr, never into the protocol
    calls = os.fdopen(os.dup(0), "rb")
    os.dup2(os.open(os.devnull, os.O_RDONLY), 0)
    functions: dict[str, Callable[..., Any]] = {}
    models: dict[int, Any] = {}
    while True:
        try:
            message = _read(calls)
        except EOFError:
            return
        except Exception as exc:  # unpickling loads the plugin (PluginError) or its model: answered, not fatal
            answer = (*_failure(exc), False)
        else:
            answer = _served(message, functions, models)
        try:
            _write(answers, answer)
        except OSError:           # the parent is gone (a worker stopped on Ctrl-C): nobody to answer, nothing to say
            os._exit(0)


def _served(message: tuple, functions: dict[str, Callable[..., Any]], models: dict[int, Any]) -> tuple:
    """The answer to one call (:func:`serve`); the function and model it brings are kept for the next calls."""
    forget, key, function, token, model, args = message
    if forget:
        models.clear()
    functions.setdefault(key, function)
    models.setdefault(token, model)
    return (*_answer(functions[key], models[token], args), True)


def _answer(function: Callable[..., Any], model, args: tuple) -> tuple[bool, Any]:
    try:
        return True, function(model, *args)
    except Exception as exc:  # the plugin's own exception crosses back as it is
        return _failure(exc)


def _failure(exc: Exception) -> tuple[bool, Exception]:
    """``(False, exc)``, or a RuntimeError with its type and text when ``exc`` does not survive pickling."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:  # an exception that does not pickle and unpickle: its type and text are kept
        exc = RuntimeError(f"{type(exc).__name__}: {exc}")
    return False, exc
