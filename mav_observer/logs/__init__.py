"""Flight logs other than tlogs (DataFlash, ULog, raw MAVLink captures) read as MAVLink."""
