"""``python -m crosscheck.bench_report [JSON [DIR]]``: the speed-against-accuracy report and its charts rendered again
from the measurements' JSON (default ``reports/speed_accuracy.json``, next to it unless DIR is given), without
measuring anything. The stable command the documentation gives; the report itself is
``crosscheck.reports.bench_report``.
"""

import sys
from pathlib import Path

from crosscheck.reports.bench_report import write_from_json

if __name__ == "__main__":
    print(write_from_json(Path(sys.argv[1] if len(sys.argv) > 1 else "reports/speed_accuracy.json"),
                          Path(sys.argv[2]) if len(sys.argv) > 2 else None))
