from opalflow.cli import main

raise SystemExit(main())
