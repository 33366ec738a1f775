"""Picture sheets the command line draws: the gallery and the inspect sheet."""
