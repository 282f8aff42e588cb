import sys

from mvracklay.cli import main

sys.exit(main())
