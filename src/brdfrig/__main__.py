import sys

from brdfrig.cli.main import main

sys.exit(main())
