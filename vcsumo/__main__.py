"""``python -m vcsumo``: the ``vcsumo`` console script (:func:`vcsumo.cli.main.main`)."""

import sys

from vcsumo.cli.main import main

sys.exit(main())
