from opalflow.cli import main
from opalflow.heap import keep_freed_memory

keep_freed_memory()
raise SystemExit(main())
