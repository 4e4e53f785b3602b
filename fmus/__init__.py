"""C sources of the plant FMUs, shipped as package data (see fmus/README.md)."""
