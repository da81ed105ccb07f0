from normbox_lab.cli import main

raise SystemExit(main())
