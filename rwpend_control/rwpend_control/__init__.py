"""Control laws, gain design and switching of the book, and the controller node."""
