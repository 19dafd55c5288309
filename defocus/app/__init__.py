"""The workflows behind the commands: each returns its results and reports progress through a
`report(text)` callback (the command line passes `print`); none of them prints or parses
options."""
