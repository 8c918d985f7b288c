"""The `stella` commands by group, each declaring its options beside its handler (harness/tools/cli.py assembles them)."""
