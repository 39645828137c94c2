"""Command-line interface: ``tepinn-flight <command>``; one module per subcommand."""
