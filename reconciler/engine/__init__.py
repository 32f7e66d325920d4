"""The engine: the executor and its steps, the read-only probes, and the files lpam owns
(the state record, the journal, generations, LPAM's layouts)."""
