"""All file I/O of r2s. Physics and geometry code never touches a file."""
