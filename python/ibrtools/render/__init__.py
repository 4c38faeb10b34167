"""Novel-view methods: each module renders cameras of a scene; methods.py is the registry."""
