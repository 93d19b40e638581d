"""``python -m packlab.vlm.serve``: the ``packlab serve`` command on its own."""

from packlab.vlm.serve.command import main

raise SystemExit(main())
