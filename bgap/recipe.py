from bgap.runner.numerics import command

main = command("bgap.commands.recipe")
if __name__ == "__main__":
    main()
