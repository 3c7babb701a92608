"""Contract test kits that plugin authors run with pytest against their own backends."""
