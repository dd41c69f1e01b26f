"""``python -m heli_uq.cli``."""

from heli_uq.cli.main import main

raise SystemExit(main())
