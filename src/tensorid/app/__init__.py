"""The application: model and data files, the command line's fit and simulate, the
reports they write and the live progress they show. It reads the engine and the
fitting layer and adds files and terminals."""
