"""Knowledge-based planners, the fixture designer's own methods: ``rules`` (fixturing rules by hand) and
``cbr`` (case-based reasoning)."""
