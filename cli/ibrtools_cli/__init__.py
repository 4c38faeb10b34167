"""Command-line front of ibrtools: parse arguments, call the library, print a table."""
