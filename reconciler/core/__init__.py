"""The pure core: planning, documents, the vehicle's policy, the phone's protocol and the
rules of status publishing. No I/O of its own."""
