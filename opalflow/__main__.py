from opalflow.cli import main
from opalflow.heap import keep_freed_memory, no_huge_page_advice

keep_freed_memory()
no_huge_page_advice()
raise SystemExit(main())
