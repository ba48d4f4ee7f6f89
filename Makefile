# Thin wrappers over scripts/ (the README's two commands are the scripts themselves).
.PHONY: walk test
walk:
	bash scripts/walk.sh
test:
	bash scripts/test.sh
