"""Task executor: learns forward models, requests plans and executes primitives."""
