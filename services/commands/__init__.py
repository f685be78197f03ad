"""Sub-commands of the ``polartrack`` command line, one module each."""
