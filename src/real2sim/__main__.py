from real2sim.cli import main

raise SystemExit(main())
