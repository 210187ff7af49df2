"""One module per ``vipm-track`` subcommand; ``common`` holds the option groups they share."""
