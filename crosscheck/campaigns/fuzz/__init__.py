"""Fuzzing campaigns: random mechanisms and states, every backend compared, each failure shrunk and saved.

A campaign is a deterministic sequence of chunks k = 0, 1, 2, ... Chunk k is one Hypothesis run (seeded from the
campaign seed and k, no example database, no deadline, ``chunk_examples`` examples) of a property that draws a model
(``crosscheck.testing.models``), up to ``max_states`` admissible states, a chart and a rigid frame, evaluates every
backend at each state with the gate's comparison, chart, frame and conservation checks (``crosscheck.engine``), tells
Hypothesis the worst error/tolerance ratio (``hypothesis.target``) and fails when a state fails (a disagreement or a
backend error). Hypothesis then shrinks the failure to a minimal model and state, and the last failing call, the
minimal example, is saved as a finding; the campaign goes on with the next chunk.

A chunk's result depends only on (seed, k) and the campaign parameters, so ``--shard i/N`` (the chunks with
k % N == i) run on N machines and merged give the findings of the unsharded run, and ``--workers W`` runs chunks in
W processes (spawned, each loading the plugins by their specs; a worker process is replaced every
``CHUNKS_PER_PROCESS`` chunks, which bounds the memory the backends' per-model caches take).

A chunk generates fewer examples than it was given when it fails: Hypothesis stops generating at a chunk's first
failing example and shrinks it instead, so the rest of that chunk's examples are never drawn (a campaign of 100
examples in chunks of 10 with a failure in 8 chunks generated 56). The report and the command's summary state the
examples generated against those asked and account for every one not generated
(``crosscheck.reports.fuzz_report.account``: a chunk that ended at its failure, an interrupted chunk, a chunk not run
yet). Findings are grouped by signature (``crosscheck.reports.fuzz_report.signature``: the failing checks, the outlier,
the backends in error and the shrunk mechanism's joint types and constraint kinds), since one bug is typically found
again by many chunks.

The campaign directory holds ``campaign.json`` (the parameters; a run in a directory with the same parameters
resumes, skipping the chunks already logged and not interrupted), ``chunks.jsonl`` (one line per chunk, appended as
each ends), ``findings/ID.json`` (written atomically as soon as a chunk ends with a failure, or is interrupted with
one in hand) and ``report.md`` (written at the end, also after an interruption). A finding's ID hashes the model
digest, the state and the failing check keys, so the same failure found by a shard and by the unsharded run has the
same ID. Files are written like any other (their mode follows the umask).

Interruptions and crashes. Interrupting a campaign by any signal at any time and resuming it (the same command
again) gives the same findings as an uninterrupted run:

- SIGINT or SIGTERM, to the campaign's process alone or to its whole process group, is an orderly stop: no chunk
  starts any more, every chunk in flight is interrupted (the parent sets a flag each worker watches, so a signal
  to the parent alone reaches them), saves the failure it holds (shrunk or not, marked ``interrupted``) and is
  logged as interrupted; the chunks get ``INTERRUPT_GRACE`` seconds for that. The report is written, the run recorded
  as interrupted (the command exits 130). A signal never breaks a save or a log append: only a chunk's Hypothesis
  run is broken into, once; otherwise the signal is noted and acted on at the next example or chunk.
- SIGKILL of the campaign or of a worker loses nothing already logged or saved: files are replaced atomically,
  the chunk log is append-only and a torn last line (a crash mid-append) is ignored, and dropped at the next append;
  workers notice their parent is gone and exit at once. A worker that dies (SIGKILL, the OOM killer) stops the
  campaign in the same orderly way, with an error naming its chunk. Corrupt files give errors naming them.
- An interrupted chunk runs again on resume; its run to the end replaces the failure the interrupted run saved: a
  saved copy of a finding from a chunk that ended takes precedence over one from an interrupted chunk, and a finding
  of an interrupted chunk that no chunk of the log lists any more is deleted.
- One run at a time per campaign directory: a run (and ``merge`` into its ``--out``) holds a lock on ``DIR/.lock``,
  which the OS releases when the process ends however it ends; a second run is refused, naming the first's pid.
"""
