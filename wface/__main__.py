import sys

from wface.cli import main

sys.exit(main())
