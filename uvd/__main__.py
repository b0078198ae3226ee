import sys

from uvd.cli import main

sys.exit(main())
