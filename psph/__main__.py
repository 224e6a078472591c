from psph.cli import main

raise SystemExit(main())
