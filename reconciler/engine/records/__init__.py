"""The files lpam owns and reads back: the state record, the apply journal, the generation
folders and their metadata, LPAM's layouts, and what is done with a damaged store copy.
The engine writes them and the probes read them, so they sit below both."""
