import sys

from drake_scenes.cli.__main__ import main

sys.exit(main())
