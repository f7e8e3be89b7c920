"""``python -m eval``: the benchmark suite's runner (:mod:`eval.suite`: ``list``, ``run NAME``) and the pipeline of
its records (:mod:`eval.records`: ``records [--write | --check]``)."""

import sys

if sys.argv[1:2] == ["records"]:
    from eval.records import main as records_main

    raise SystemExit(records_main(sys.argv[2:]))

from eval.suite import main

raise SystemExit(main())
