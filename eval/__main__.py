"""``python -m eval``: the benchmark suite's runner (:mod:`eval.suite`)."""

from eval.suite import main

raise SystemExit(main())
