"""Run a test module's scenario in a child process (for client libraries, such as ur_rtde,
whose constructors hold the GIL and so cannot share a process with a mock's server threads).

The parent calls ``run_child(__file__, scenario, host, args)``: the child runs
``python -m <module> SCENARIO HOST OUT ARGS`` from the repository root, and the module ends
with ``if __name__ == "__main__": child_main(_child)``. ``_child(scenario, host, args,
result)`` fills ``result``, which ``child_main`` writes to OUT as JSON whatever happens; the
parent returns it once the child exited with status 0.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent

#: The child's work: (scenario, host, args, result to fill).
ChildFn = Callable[[str, str, dict[str, Any], dict[str, Any]], None]


def run_child(test_file: str, scenario: str, host: str, args: dict[str, Any],
              timeout_s: float = 120.0) -> dict[str, Any]:
    """Run ``test_file`` (a module under the repository) as a child process on ``scenario``
    against ``host`` with the JSON-able ``args``; return the result it wrote."""
    module = ".".join(Path(test_file).resolve().relative_to(ROOT).with_suffix("").parts)
    with tempfile.TemporaryDirectory() as d:
        out = Path(d) / "result.json"
        proc = subprocess.run([sys.executable, "-m", module, scenario, host, str(out),
                               json.dumps(args)], cwd=ROOT, capture_output=True, text=True,
                              timeout=timeout_s)
        assert proc.returncode == 0, f"child failed:\n{proc.stdout}\n{proc.stderr}"
        return json.loads(out.read_text())


def child_main(child: ChildFn) -> None:
    """The child's side: parse ``SCENARIO HOST OUT ARGS`` from ``sys.argv``, run
    ``child(scenario, host, args, result)`` and write ``result`` to OUT even if it raised."""
    scenario, host, out, args = sys.argv[1], sys.argv[2], sys.argv[3], json.loads(sys.argv[4])
    result: dict[str, Any] = {}
    try:
        child(scenario, host, args, result)
    finally:
        Path(out).write_text(json.dumps(result))
