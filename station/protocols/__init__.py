"""Numbers that a wire protocol defines, shared by the driver that reads them and the fake that sends them."""
