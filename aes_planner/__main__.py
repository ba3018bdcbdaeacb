from aes_planner.cli import main

raise SystemExit(main())
