"""``python -m abcgs.masks.page``: the masks page (:mod:`abcgs.masks.page.command`)."""

if __name__ == "__main__":
    from abcgs.runtime import setup

    setup()  # the process settings (abcgs.runtime.setup): the wait policy only where torch is not loaded yet

    from abcgs.masks.page.command import main

    raise SystemExit(main())
