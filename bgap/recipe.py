from bgap.runner.numerics import command

main = command("bgap.experiments.recipe")
if __name__ == "__main__":
    main()
