"""Application layer: command line, scene driver and run loop, frame rendering,
figures and file output.  Nothing below this layer knows about files, plots or
command lines."""
