import sys

from mvracklay.threads import quiet_openmp

quiet_openmp()  # before torch loads (mvracklay/threads.py)

from mvracklay.cli import main  # noqa: E402

sys.exit(main())
