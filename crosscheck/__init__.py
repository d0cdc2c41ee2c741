"""The harness: everything that is not physics (docs/design.md, "Architecture").

By concern: ``core`` (the ruler: sampling, tolerance, comparison), ``checks`` (charts, frames, invariance,
conservation, linearization, equilibria), ``guards`` (the conditioning audit, coverage, preflight, the self-test
canaries), ``references`` (Pinocchio built from the model file, the 50-digit reference, the closed forms),
``engine`` (the gate's run), ``faults``, ``campaigns``, ``reports`` and ``cli``. The public import paths a user or a
plugin takes are ``crosscheck.gate``, ``crosscheck.backends``, ``crosscheck.needs``, ``crosscheck.assemble`` and
``crosscheck.testing`` (docs/layout.md).
"""

import os
import signal
import sys

#: The environment variable that marks a pool's worker process: it holds the pid of the process that started the
#: pool (``crosscheck.engine.workers``). A direct child of that process that multiprocessing spawned (its command line
#: ends in ``--multiprocessing-fork``) ignores SIGINT from here on, before the imports that follow (seconds on a busy
#: machine) could be broken into by a Ctrl-C meant for its parent. Any other child (a ``crosscheck`` command run by
#: a process whose variable is set, as a test suite does) keeps its Ctrl-C.
WORKER = "CROSSCHECK_WORKER"

if os.environ.get(WORKER) == str(os.getppid()) and sys.argv[-1:] == ["--multiprocessing-fork"]:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
