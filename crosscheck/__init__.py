"""The harness: everything that is not physics (DESIGN.md).

Sampling (``sampling``), the tolerance policy (``tolerance``), comparison and verdicts (``compare``),
the equivalence gate (``gate``), markdown reports (``report``) and the command line (``cli``).
The Pinocchio reference lives in ``reference``, apart from the formalisms it checks.
"""

import os
import signal
import sys

#: The environment variable that marks a pool's worker process: it holds the pid of the process that started the
#: pool (``crosscheck.engine.workers``). A direct child of that process that multiprocessing spawned (its command line ends
#: in ``--multiprocessing-fork``) ignores SIGINT from here on, before the imports that follow (seconds on a busy
#: machine) could be broken into by a Ctrl-C meant for its parent. Any other child (a ``crosscheck`` command run by
#: a process whose variable is set, as a test suite does) keeps its Ctrl-C.
WORKER = "CROSSCHECK_WORKER"

if os.environ.get(WORKER) == str(os.getppid()) and sys.argv[-1:] == ["--multiprocessing-fork"]:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
