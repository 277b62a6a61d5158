"""``python -m belief_nlp.cli``: the same as the ``belief-nlp`` command."""

import sys

from . import main

sys.exit(main())
