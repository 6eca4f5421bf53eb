"""Reading and decoding logs: CAN readers, DBC decoding, signal maps, GNSS/INS, alignment,
resampling, the canonical Recording, ingest and info. Imports only hmpc.models.errors and
numpy/cantools/python-can.
"""
