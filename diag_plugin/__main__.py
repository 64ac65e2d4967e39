import sys

from diag_plugin.cli import main

sys.exit(main())
