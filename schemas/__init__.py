"""Pydantic models of every document lpam reads or writes.

`json/` holds the JSON Schemas exported from these models (`python -m schemas.export`);
a test keeps the committed files equal to what the models produce.
"""
