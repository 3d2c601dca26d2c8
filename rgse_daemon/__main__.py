from rgse_daemon.cli import main

raise SystemExit(main())
