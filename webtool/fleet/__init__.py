"""The Fleet page's area: every drone the station hears (``drovisio station``)."""
