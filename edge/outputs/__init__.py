"""Outputs: Modbus register image and servers, CAN object list."""
